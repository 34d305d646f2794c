"""A :class:`Snapshot` from a gateway over Zenoh, for a technician on another machine.

Only history queries (``serra/<farm>/*/history/...``, answered from the gateway's store): every
refresh asks for the latest message of every key (``?last=1``) and for the measurements and
forecasts since the last refresh (24 h the first time, for the sparklines and the forecast error).
It never subscribes: a subscriber on ``serra/**`` would count as a listener, and the gateway would
mark its backlog sent while the cloud is away (store-and-forward holds a message until somebody
matches its key). So the screen shows the gateway's store, sent or not, and changes nothing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

import zenoh

from gateway.publish import zconfig
from gateway.status import snapshot as S
from gateway.status.messages import Messages

SERIES_KINDS = ("measurement/**", "forecast", "finding")
LIMIT = 100_000


class ZenohSource:
    def __init__(self, connect: Sequence[str], mode: str = "peer", farm: str = "*",
                 timeout: float = 10.0, bins: int = S.FINE_BINS) -> None:
        self.connect, self.mode, self.farm, self.timeout = list(connect), mode, farm, timeout
        self.session = zenoh.open(zconfig.build(mode, self.connect, [], dial_only=True))
        self.messages = Messages(bins)
        self.since: dict[str, float] = {}  # series kind → newest gateway time asked for
        self.answered: bool | None = None
        self.error = ""
        self._lock = threading.Lock()

    @property
    def label(self) -> str:
        return f"zenoh {', '.join(self.connect)}"

    def close(self) -> None:
        self.session.close()

    def _get(self, selector: str) -> int:
        """Feed every reply of one history query to :attr:`messages`; returns the replies."""
        n = 0
        for reply in self.session.get(selector, consolidation=zenoh.ConsolidationMode.NONE,
                                      timeout=self.timeout):
            if reply.ok is not None:
                n += 1
                self.messages.add(str(reply.ok.key_expr), reply.ok.payload.to_bytes())
            else:
                self.error = reply.err.payload.to_string() if reply.err is not None else "error"
        return n

    def snapshot(self) -> S.Snapshot:
        with self._lock:
            wall = time.time()
            self.error = ""
            base = f"serra/{self.farm}/*/history"
            n = self._get(f"{base}/**?last=1")
            now = self.messages.newest
            if now is not None:
                for kind in SERIES_KINDS:
                    start = self.since.get(kind, now - S.DAY - 7200 if kind != "finding" else None)
                    frm = f"from={_iso(start - 120)};" if start is not None else ""
                    n += self._get(f"{base}/{kind}?{frm}limit={LIMIT}")
                    self.since[kind] = now
                self.messages.trim()
            self.answered = n > 0 if self.answered is None or n > 0 else False
            return self.messages.snapshot(self.label, wall, self.answered, self._link(n),
                                          (f"a query failed: {self.error}",) if self.error else ())

    def _link(self, replies: int) -> S.Link:
        # no endpoints: a Link's are where the gateway listens, which this screen cannot know;
        # the ones it dials are in its own words here and on the Source line
        info = self.session.info
        peers, routers = len(info.peers_zid()), len(info.routers_zid())
        if peers + routers == 0:
            return S.Link(True, False, f"this screen: nobody reachable at {', '.join(self.connect)}")
        who = f"{peers} peer{'s' * (peers != 1)}" + (f", {routers} router{'s' * (routers != 1)}"
                                                    if routers else "")
        if replies:
            return S.Link(True, True, f"this screen: connected ({who}), the gateway answers")
        return S.Link(True, None, f"this screen: connected ({who}), no gateway answers")


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))

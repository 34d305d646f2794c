"""Store-and-forward: the outbox drained onto Zenoh, in order, only where somebody listens.

A Zenoh ``put`` with nobody matching is dropped silently, so a message leaves the outbox only
through a key that a subscriber (or a router) matches: per key, in ``id`` order, with congestion
control BLOCK (a burst or a backlog is never dropped by Zenoh). A key nobody matches holds its
messages (and only its own) until a subscriber appears; then its backlog drains in order.

Each key has an advanced publisher (zenoh-ext: a cache of the last ``cache`` samples,
sample-miss detection with sporadic heartbeats, publisher detection), so an advanced subscriber
recovers samples lost between a silent link loss and its detection; the advanced publisher has
no matching API, so a plain publisher on the same key reports the matching status.

Crash safety: messages are marked sent after they were handed to Zenoh. A crash before the mark
costs a repeat after the restart; one after it could lose what was still in Zenoh's queues, so a
restart first puts again (before anything newer on the same key) what was sent in the last
``resend_s`` before it; repeats are dropped by the subscriber by their idempotency key.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import zenoh
from zenoh.ext import CacheConfig, MissDetectionConfig, declare_advanced_publisher

from gateway.store.db import close_db, open_db
from gateway.store.outage import Outage
from gateway.store.outbox import Outbox, Pending

log = logging.getLogger("serra.publish")
BATCH = 256
UNHEARD_WARN_S = 60.0  # [s, gateway clock] linked but nobody listening this long: say it once


@dataclass
class LinkState:
    """What the status screen shows about the link (written to gateway_status['zenoh'])."""

    mode: str = ""
    zid: str = ""
    peers: int = 0
    routers: int = 0
    matched_keys: int = 0
    waiting_keys: list[str] = field(default_factory=list)  # keys holding messages, nobody listening
    published: int = 0
    last_put: float | None = None  # gateway clock
    resent_on_start: int = 0


class _Key:
    __slots__ = ("adv", "plain")

    def __init__(self, session: zenoh.Session, key: str, cache: int) -> None:
        self.adv = declare_advanced_publisher(
            session, key, encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.BLOCK,
            cache=CacheConfig(max_samples=cache),
            sample_miss_detection=MissDetectionConfig(heartbeat=None, sporadic_heartbeat=1.0),
            publisher_detection=True)
        self.plain = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)

    def matching(self) -> bool:
        # zenoh's stub says matching_status is a bool; it is a MatchingStatus (zenoh 1.x)
        return bool(self.plain.matching_status.matching)  # type: ignore[attr-defined]

    def close(self) -> None:
        for p in (self.adv, self.plain):
            try:
                p.undeclare()
            except zenoh.ZError:
                pass


class OutboxPublisher:
    """A thread that drains the outbox (its own SQLite connection) onto a Zenoh session."""

    def __init__(self, session: zenoh.Session, db: Path, *, cache: int = 16, resend_s: float = 0.0,
                 clock: Callable[[], float] = time.time, mode: str = "peer",
                 max_rows: int = 100_000, alarm_fraction: float = 0.8,
                 outage: Outage | None = None) -> None:
        """``outage``: the service's, told when the outbox cannot be marked sent (the messages
        already put are put again once it can: the cloud drops repeats)."""
        self.outage = outage
        self.session, self.db, self.cache, self.resend_s, self.clock = session, db, cache, resend_s, clock
        self.max_rows, self.alarm_fraction = max_rows, alarm_fraction
        self.keys: dict[str, _Key] = {}
        self.resend: list[Pending] = []  # sent just before a restart: put again first
        self.state = LinkState(mode=mode, zid=str(session.info.zid()))
        self.wake = threading.Event()
        self.drained = threading.Event()  # set after each drain pass
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._unheard_since: float | None = None  # linked, messages held, no key matched since
        self._said_unheard = False
        self._thread = threading.Thread(target=self._run, name="serra-publish", daemon=True)

    def kick(self, wait: float = 0.0) -> None:
        """Wake the publisher; with ``wait``, give it up to that long [s] to put what is new
        (the caller's CPU work would otherwise slow it down through the GIL)."""
        self.drained.clear()
        self.wake.set()
        if wait > 0:
            self.drained.wait(wait)

    def start(self) -> None:
        self._thread.start()
        self._ready.wait(timeout=60)

    def stop(self, timeout: float = 30.0) -> None:
        """Finish the batch in hand, then undeclare every publisher (before the session closes)."""
        self._stop.set()
        self.wake.set()
        if self._thread.ident is not None:  # started
            self._thread.join(timeout)
        for k in self.keys.values():
            k.close()
        self.keys.clear()

    @property
    def error(self) -> BaseException | None:
        return self._error

    def _run(self) -> None:
        conn = open_db(self.db)
        try:
            outbox = Outbox(conn, self.max_rows, self.alarm_fraction)
            if self.resend_s > 0:
                self.resend = outbox.sent_recently(self.resend_s)
                self.state.resent_on_start = len(self.resend)
                if self.resend:
                    log.info("putting again the %d messages sent in the last %g s before the "
                             "restart (the cloud drops repeats)", len(self.resend), self.resend_s)
            self._ready.set()
            while not self._stop.is_set():
                try:
                    waiting = self.drain(outbox)
                except Exception as e:  # a store that cannot be written: put again later
                    delay = self.outage.failed("publisher", e) if self.outage else None
                    if delay is None:
                        raise
                    self._stop.wait(delay)
                    continue
                if self.outage is not None:
                    self.outage.ok("publisher")
                self.drained.set()
                # Nobody listens on some key: look again soon (a subscriber may have come).
                self.wake.wait(0.2 if waiting else 1.0)
                self.wake.clear()
            self._final_drain(outbox)
        except BaseException as e:  # surfaced by the service, which stops
            self._error = e
            log.error("publisher stopped: %s", e)
        finally:
            self._ready.set()
            close_db(conn)

    def _final_drain(self, outbox: Outbox) -> None:
        """What the service made while stopping; a store failing then is the outage's."""
        try:
            self.drain(outbox, final=True)
        except Exception as e:
            if self.outage is None or self.outage.failed("publisher", e) is None:
                raise

    def _key(self, key: str) -> _Key:
        k = self.keys.get(key)
        if k is None:
            k = self.keys[key] = _Key(self.session, key, self.cache)
        return k

    def _put_resends(self, blocked: set[str]) -> list[Pending]:
        """Put again, in order, the messages sent just before the restart whose key matches;
        returns those still waiting (their keys are added to ``blocked``: order per key)."""
        left = []
        for m in self.resend:
            if m.key not in blocked and self._key(m.key).matching():
                self._key(m.key).adv.put(m.payload)
            else:
                blocked.add(m.key)
                left.append(m)
        return left

    def drain(self, outbox: Outbox, final: bool = False) -> int:
        """Put every unsent message whose key is matched, per key in order; returns how many
        keys hold messages that nobody listens to."""
        after = 0
        blocked: set[str] = set()
        if self.resend:
            self.resend = self._put_resends(blocked)
        while final or not self._stop.is_set():
            batch = outbox.peek(BATCH, after)
            if not batch:
                break
            sent = []
            for m in batch:
                if m.key in blocked:
                    continue  # an earlier message of this key waits: keep the order
                k = self._key(m.key)
                if not k.matching():
                    blocked.add(m.key)
                    continue
                k.adv.put(m.payload)
                sent.append(m.id)
            if sent:
                outbox.mark_sent(sent, self.clock())
                self.state.published += len(sent)
                self.state.last_put = self.clock()
            after = batch[-1].id
        info = self.session.info
        self.state.peers, self.state.routers = len(info.peers_zid()), len(info.routers_zid())
        self.state.matched_keys = sum(k.matching() for k in self.keys.values())
        self.state.waiting_keys = sorted(blocked)
        self._watch_unheard()
        return len(blocked)

    def _watch_unheard(self) -> None:
        """Say once when the session has a router or peer but, for UNHEARD_WARN_S, no key holding
        messages has a subscriber: from the gateway that looks the same whether the cloud
        subscriber is down or the routers' access control refuses this gateway (it is then
        never told of any subscription), so name both, with the zid a refusing router logs."""
        s = self.state
        if not (s.peers or s.routers) or not s.waiting_keys or s.matched_keys:
            self._unheard_since, self._said_unheard = None, False
            return
        now = self.clock()
        if self._unheard_since is None:
            self._unheard_since = now
        elif not self._said_unheard and now - self._unheard_since >= UNHEARD_WARN_S:
            self._said_unheard = True
            log.warning(
                "linked to %d router(s) and %d peer(s) for %.0f s but nobody listens to the %d "
                "keys holding messages (%s%s); they stay in the outbox. Is the cloud subscriber "
                "running? Behind access control: is this farm in the routers' [access].gateways? "
                "(a router refusing this gateway logs '%s did not match any configured ACL "
                "subject')", s.routers, s.peers, now - self._unheard_since, len(s.waiting_keys),
                s.waiting_keys[0], ", ..." if len(s.waiting_keys) > 1 else "", s.zid)

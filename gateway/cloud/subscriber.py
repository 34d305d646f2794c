"""The cloud side: a Zenoh subscriber storing every Serra message once (``python -m gateway
subscribe``), and the kit CSV per greenhouse rebuilt from the measurements it received.

It declares a zenoh-ext advanced subscriber: on joining it asks each publisher for its cache
(``HistoryConfig``), and with heartbeat recovery it detects and fetches samples it missed
(``RecoveryConfig``); repeats from either path, and from a gateway re-sending after a restart,
are dropped by idempotency key in the store. Samples arrive on Zenoh's threads; one writer
thread stores them in batches.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.cloud.store import CloudStore, NotAMessage, Received, SqliteCloudStore, parse
from gateway.kitcsv import write_kit_csv

log = logging.getLogger("serra.cloud")


@dataclass
class SubscribeStats:
    received: int = 0
    stored: int = 0
    repeats: int = 0
    not_messages: int = 0
    missed: int = 0  # samples Zenoh reported missed (then recovered from the publisher's cache, or not)


class Subscriber:
    """Subscribe to ``key`` on a session built from ``connect``/``listen``/``mode``."""

    def __init__(self, store: CloudStore, connect: Sequence[str] = (), key: str = "serra/**",
                 mode: str = "peer", listen: Sequence[str] = ()) -> None:
        self.store, self.key = store, key
        self.connect, self.listen, self.mode = list(connect), list(listen), mode
        self.stats = SubscribeStats()
        self._q: queue.Queue[tuple[str, bytes] | None] = queue.Queue()
        self._writer = threading.Thread(target=self._write, name="serra-cloud-writer", daemon=True)
        self._idle = threading.Condition()
        self._queued = 0  # samples handed to the writer (under _idle)
        self._done = 0  # samples the writer has dealt with
        self.session = self.sub = self.miss = None
        self.error: BaseException | None = None

    def start(self) -> None:
        import zenoh
        from zenoh.ext import HistoryConfig, RecoveryConfig, declare_advanced_subscriber

        from gateway.publish import zconfig

        self.session = zenoh.open(zconfig.build(self.mode, self.connect, self.listen))
        self._writer.start()
        self.sub = declare_advanced_subscriber(
            self.session, self.key, self._on_sample,
            history=HistoryConfig(detect_late_publishers=True),
            recovery=RecoveryConfig(heartbeat=True))
        self.miss = self.sub.sample_miss_listener(self._on_miss)

    def _on_sample(self, sample) -> None:
        with self._idle:
            self._queued += 1
        self._q.put((str(sample.key_expr), sample.payload.to_bytes()))

    def _on_miss(self, miss) -> None:
        self.stats.missed += int(miss.nb)

    def _write(self) -> None:
        store_open = True
        while store_open:
            item = self._q.get()
            batch = [item]
            while len(batch) < 1000:
                try:
                    batch.append(self._q.get_nowait())
                except queue.Empty:
                    break
            if None in batch:
                store_open = False
            msgs: list[Received] = []
            for it in batch:
                if it is None:
                    continue
                self.stats.received += 1
                try:
                    msgs.append(parse(*it))
                except NotAMessage as e:
                    self.stats.not_messages += 1
                    log.warning("not a Serra message: %s", e)
            try:
                new = self.store.add(msgs)
            except Exception as e:  # the store failed: say so once, stop storing
                self.error = e
                log.error("cloud store failed: %s", e)
                return
            self.stats.stored += new
            self.stats.repeats += len(msgs) - new
            with self._idle:
                self._done += sum(it is not None for it in batch)
                self._idle.notify_all()

    def wait_idle(self, timeout: float) -> bool:
        """Wait until every sample received so far is stored (tests, shutdown)."""
        with self._idle:
            return self._idle.wait_for(lambda: self._done >= self._queued, timeout)

    def stop(self) -> None:
        """Undeclare (a declared callback blocks interpreter exit), close, store what came."""
        for ent in (self.miss, self.sub):
            if ent is not None:
                try:
                    ent.undeclare()
                except Exception:
                    pass
        if self.session is not None:
            self.session.close()
        self.session = self.sub = self.miss = None
        if self._writer.is_alive():
            self._q.put(None)
            self._writer.join(timeout=30)


# -- kit CSV from the cloud's copy ----------------------------------------------------------------
SIDE_COLUMNS = {
    "measurement/inside": {"temperature": ("t_in", 1.0), "relativeHumidity": ("rh_in", 100.0)},
    "measurement/outside": {"temperature": ("t_out", 1.0), "relativeHumidity": ("rh_out", 100.0),
                            "solarRadiation": ("i_glob", 1.0), "windSpeed": ("wind", 1.0),
                            "rainDetected": ("rain", 1.0)},
}


def export_kit_csv(store: SqliteCloudStore, farm: str, greenhouse: str, path: Path) -> int:
    """The greenhouse's measurements as a kit CSV on the minute grid (mean of the records in each
    minute; rain 1 when any record of the minute was wet); returns the rows written."""
    acc: dict[int, dict[str, list[float]]] = {}
    for kind, attrs in SIDE_COLUMNS.items():
        for m in store.messages(farm, greenhouse, kind):
            if m.t is None:
                continue
            doc = json.loads(m.payload)
            row = acc.setdefault(int(m.t // 60 * 60), {})
            for attr, (col, factor) in attrs.items():
                if attr in doc:
                    row.setdefault(col, []).append(float(doc[attr]["value"]) * factor)
    if not acc:
        return 0
    minutes = sorted(acc)
    cols = {}
    for col in ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "rain"):
        vals = [acc[m].get(col) for m in minutes]
        mean = [float(np.mean(v)) if v else math.nan for v in vals]
        if col == "rain":
            mean = [float(x > 0) if not math.isnan(x) else math.nan for x in mean]
        cols[col] = np.array(mean)
    write_kit_csv(path, np.array(minutes, dtype="int64").astype("datetime64[s]"), cols)
    return len(minutes)

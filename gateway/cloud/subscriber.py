"""The cloud side: a Zenoh subscriber storing every Serra message once (``python -m gateway
subscribe``), and the kit CSV per greenhouse rebuilt from the measurements it received.

It declares a zenoh-ext advanced subscriber per key expression (one per farm behind the routers'
access control: gateway.net.acl.AccessSpec.subscriptions) with heartbeat recovery
(``RecoveryConfig``: it detects and fetches from the publisher's cache samples it missed), and on
each join it catches up from the gateways' history (gateway/cloud/catchup.py). It does not ask the
publishers' caches on joining (``HistoryConfig``): with that, zenoh-ext 1.10 can drop a backlog
drained while its first query runs (docs/cloud.md, "Joining while a backlog drains"). Repeats
from any path, and from a gateway re-sending after a restart, are dropped by idempotency key in
the store. Samples arrive on Zenoh's threads, are
stamped with their arrival time, and one writer thread stores them in batches; a batch the
store refuses (the database is down) is kept and retried, never dropped. With ``history_farms``
it also answers history queries for those farms from the store (gateway/cloud/history.py).

In client mode the session opens when a router answers (gateway.net.session.SessionOpener).
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gateway.cloud.store import CloudStore, NotAMessage, Received, parse
from gateway.kitcsv import write_kit_csv

log = logging.getLogger("serra.cloud")
BATCH = 1000  # messages per store transaction at most
RETRY_MAX_S = 30.0  # longest wait between attempts to store a refused batch


@dataclass
class SubscribeStats:
    received: int = 0  # samples and catch-up replies that arrived (stored, repeats, or held)
    stored: int = 0
    repeats: int = 0
    not_messages: int = 0
    missed: int = 0  # samples Zenoh reported missed (then recovered from the publisher's cache, or not)
    caught_up: int = 0  # history replies received by the catch-up on joining (new or repeats)
    catch_up_errors: int = 0
    store_retries: int = 0  # batches the store refused at first (kept and retried)
    store_s: float = 0.0  # wall seconds spent storing (rows / store_s: what the store sustains)


class Subscriber:
    """Subscribe to ``keys`` on a session built from ``connect``/``listen``/``mode`` (+ ``extra``
    Zenoh config entries: TLS, reconnection; gateway.net.zenohcfg.session_entries)."""

    def __init__(self, store: CloudStore, connect: Sequence[str] = (),
                 keys: str | Sequence[str] = "serra/**", mode: str = "peer",
                 listen: Sequence[str] = (), extra: Mapping[str, Any] | None = None,
                 history_farms: Sequence[str] = (), retry: Any = None) -> None:
        self.store = store
        self.keys = [keys] if isinstance(keys, str) else list(keys)
        self.key = ", ".join(self.keys)  # for messages
        self.connect, self.listen, self.mode = list(connect), list(listen), mode
        self.extra, self.history_farms, self.retry = dict(extra or {}), list(history_farms), retry
        self.stats = SubscribeStats()
        self._q: queue.Queue[tuple[str, bytes, float] | None] = queue.Queue()
        self._writer = threading.Thread(target=self._write, name="serra-cloud-writer", daemon=True)
        self._idle = threading.Condition()
        self._queued = 0  # samples handed to the writer (under _idle)
        self._done = 0  # samples the writer has dealt with
        self._closing = threading.Event()  # stop() was called: a refused batch gets one last try
        self.session: Any = None
        self.subs: list[Any] = []
        self.history: Any = None
        self.opener: Any = None
        self.error: BaseException | None = None
        self.store_failing = ""  # why the store refuses the batch in hand ("": it does not)
        self.catching_up: threading.Thread | None = None
        self._cancel: Any = None  # the catch-up's zenoh.CancellationToken
        self.caught_up = threading.Event()  # set when the catch-up of the last join has ended

    def start(self) -> bool:
        """Open the session and subscribe (client mode: retried in the background while no
        router answers; :attr:`ready` is set once subscribed). True if subscribed now."""
        from gateway.net.session import SessionOpener
        from gateway.publish import zconfig

        self._writer.start()
        self.opener = SessionOpener(
            lambda: zconfig.build(self.mode, self.connect, self.listen, extra=self.extra,
                                  dial_only=bool(self.connect)),
            self._declare, self.retry, what=f"zenoh {self.mode} of {', '.join(self.connect) or '-'}")
        if self.mode != "client":  # a peer opens without anyone to talk to: an error is final
            if not self.opener.start(background=False):
                raise RuntimeError(self.opener.state.last_error)
        elif not self.opener.start():
            return False
        if self.opener.error is not None:
            raise self.opener.error
        return True

    @property
    def ready(self) -> threading.Event:
        return self.opener.opened

    def _declare(self, session: Any) -> None:
        import zenoh
        from zenoh.ext import RecoveryConfig, declare_advanced_subscriber

        from gateway.cloud.history import CloudHistory

        self.session = session
        self.caught_up.clear()
        try:
            latest = self._latest()  # before anything new arrives: where the catch-up starts
            for key in self.keys:
                # periodic_queries=None is zenoh's default; its stub marks the argument required
                recovery = RecoveryConfig(periodic_queries=None, heartbeat=True)
                sub = declare_advanced_subscriber(session, key, self._on_sample, recovery=recovery)
                self.subs.append((sub, sub.sample_miss_listener(self._on_miss)))
            if self.history_farms:
                self.history = CloudHistory(session, self.store, self.history_farms)
        except BaseException:
            self._undeclare()
            self.session = None
            raise
        self._cancel = zenoh.CancellationToken()
        self.catching_up = threading.Thread(target=self._catch_up, args=(session, latest, self._cancel),
                                            name="serra-cloud-catch-up", daemon=True)
        self.catching_up.start()

    def _latest(self) -> dict[str, float]:
        reader = self.store.reader()  # the writer thread owns the store's own connection
        try:
            return reader.latest()
        finally:
            reader.close()

    def _catch_up(self, session: Any, latest: dict[str, float], cancel: Any) -> None:
        from gateway.cloud.catchup import run_logged

        try:
            stats = run_logged(session, self.keys, latest, self._on_raw, cancel)
            self.stats.caught_up += stats.replies
            self.stats.catch_up_errors += len(stats.errors)
        finally:
            self.caught_up.set()

    def _on_sample(self, sample) -> None:
        self._on_raw(str(sample.key_expr), sample.payload.to_bytes())

    def _on_raw(self, key: str, payload: bytes) -> None:
        with self._idle:
            self._queued += 1
            self.stats.received += 1  # on arrival: while the store refuses, received > stored
        self._q.put((key, payload, time.time()))

    def _on_miss(self, miss) -> None:
        self.stats.missed += int(miss.nb)

    def _write(self) -> None:
        store_open = True
        while store_open:
            item = self._q.get()
            batch = [item]
            while len(batch) < BATCH:
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
                try:
                    msgs.append(parse(*it))
                except NotAMessage as e:
                    self.stats.not_messages += 1
                    log.warning("not a Serra message: %s", e)
            new = self._store(msgs)
            if new is None:
                return
            self.stats.stored += new
            self.stats.repeats += len(msgs) - new
            with self._idle:
                self._done += sum(it is not None for it in batch)
                self._idle.notify_all()

    def _store(self, msgs: list[Received]) -> int | None:
        """Store a batch, retrying while the store refuses it; None if stopped before that
        (:attr:`error` then says how many messages were not stored)."""
        wait, failing, since = 0.5, "", time.monotonic()
        while True:
            t0 = time.perf_counter()
            try:
                new = self.store.add(msgs)
            except Exception as e:
                text = str(e).splitlines()[0] if str(e) else type(e).__name__
                if text != failing:
                    log.error("cloud store refused %d messages (%s); kept, retrying", len(msgs), text)
                    failing = self.store_failing = text
                self.stats.store_retries += 1
                if self._closing.is_set():  # stopping, and the last try failed: give up
                    with self._idle:
                        held = self._queued - self._done  # this batch and those queued after it
                    self.error = RuntimeError(f"stopped with {held} messages not stored: {text}")
                    return None
                self._closing.wait(wait)  # stop() wakes it for one last try
                wait = min(wait * 2, RETRY_MAX_S)
                continue
            self.stats.store_s = round(self.stats.store_s + time.perf_counter() - t0, 6)
            self.store_failing = ""
            if failing:  # a warning, as its error was: the default log level shows both
                log.warning("cloud store back after %.0f s: stored the %d kept messages",
                            time.monotonic() - since, len(msgs))
            return new

    def wait_idle(self, timeout: float) -> bool:
        """Wait until every sample received so far is stored (tests, shutdown)."""
        with self._idle:
            return self._idle.wait_for(lambda: self._done >= self._queued, timeout)

    def _undeclare(self) -> None:
        if self.history is not None:
            self.history.close()
            self.history = None
        for sub, miss in self.subs:
            for ent in (miss, sub):
                try:
                    ent.undeclare()
                except Exception:
                    pass
        self.subs = []

    def stop(self) -> None:
        """Undeclare (a declared callback blocks interpreter exit), close, store what came."""
        if self.opener is not None:
            self.opener.stop()
        if self._cancel is not None:
            self._cancel.cancel()  # a catch-up under way stops asking
        if self.catching_up is not None:
            self.catching_up.join(timeout=30)
        self._undeclare()
        if self.session is not None:
            self.session.close()
        self.session = None
        if self._writer.is_alive():
            self._closing.set()  # a batch the store refuses now is tried once more, then given up
            self._q.put(None)
            self._writer.join(timeout=60)


# -- kit CSV from the cloud's copy ----------------------------------------------------------------
SIDE_COLUMNS = {
    "measurement/inside": {"temperature": ("t_in", 1.0), "relativeHumidity": ("rh_in", 100.0)},
    "measurement/outside": {"temperature": ("t_out", 1.0), "relativeHumidity": ("rh_out", 100.0),
                            "solarRadiation": ("i_glob", 1.0), "windSpeed": ("wind", 1.0),
                            "rainDetected": ("rain", 1.0)},
}


def export_kit_csv(store: CloudStore, farm: str, greenhouse: str, path: Path) -> int:
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

"""The store-side thread of the service: new records → messages; minutes → estimators → messages;
status rows. Woken after every ingest commit and at least every ``TICK`` wall seconds (a minute
can become final by the clock alone when a kit lags)."""

from __future__ import annotations

import logging
import os
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from gateway.publish.payloads import Place
from gateway.service.clock import Clock
from gateway.service.pipeline import GreenhousePipeline
from gateway.service.producers import GreenhouseInfo, Producers
from gateway.service.resources import GreenhouseResources
from gateway.service.settings import GatewayConfig
from gateway.store.aggregate import aggregate
from gateway.store.db import close_db, open_db
from gateway.store.live import outbox_backlog, set_status
from gateway.store.outage import Outage, StoreDamaged
from gateway.store.outbox import Outbox

log = logging.getLogger("serra.gateway")
TICK = 1.0  # [wall s]
STATUS_EVERY = 5.0  # [wall s] between gateway_status writes
MAX_BATCHES = 4  # estimator batches per greenhouse per pass: records keep flowing while catching up
PUBLISH_FIRST_S = 0.05  # [wall s] the longest the estimators wait for new records to be put


def _utc(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


class Worker:
    def __init__(self, cfg: GatewayConfig, resources: list[GreenhouseResources], clock: Clock,
                 wake_publisher: Callable[[float], None],
                 status_extra: Callable[[], dict[str, Any]] = dict, publish: bool = True,
                 outage: Outage | None = None) -> None:
        """``publish``: make messages (False with Zenoh off: the estimators still run and store);
        ``outage``: the service's, told of a store that cannot be written (then waited out)."""
        self.outage = outage or Outage(cfg.db, "the estimators wait")
        self._resumed: list[str] = []  # the estimators' resume lines after a failed write
        self.cfg, self.resources, self.clock, self.publish = cfg, resources, clock, publish
        self.wake_publisher, self.status_extra = wake_publisher, status_extra
        self.wake = threading.Event()
        self._stop = threading.Event()
        self._ready = threading.Event()
        self.error: BaseException | None = None
        self.started = time.time()
        self.pipelines: list[GreenhousePipeline] = []
        self.producers: Producers | None = None
        self.outbox: Outbox | None = None
        self.passes = 0
        self.unassigned: set[int] = set()  # kits that send but no greenhouse uses (reported)
        self._thread = threading.Thread(target=self._run, name="serra-worker", daemon=True)

    def start(self) -> None:
        self._thread.start()
        self._ready.wait(timeout=120)
        if self.error is not None:
            raise self.error

    def stop(self, timeout: float = 60.0) -> None:
        """Finish the pass in hand (a last pass turns what was just stored into messages)."""
        self._stop.set()
        self.wake.set()
        if self._thread.ident is not None:  # started
            self._thread.join(timeout)

    def _setup(self, conn, again: bool = False) -> None:
        """The estimators resumed from the store, the outbox and the producers; ``again`` after
        a failed write (the warnings said at start are not said again, the resume lines kept
        for when the store writes again)."""
        est = self.cfg.estimator
        infos = {}
        self.pipelines, self._resumed = [], []
        for r in self.resources:
            s = r.settings
            p = GreenhousePipeline(s.name, r.gh, r.model, s.inside, s.outside, r.theta0,
                                   horizons=est.horizons_min, outlook=s.outlook, seed=est.seed,
                                   gap_s=est.gap_s, history_min=est.history_min,
                                   ventilation=r.ventilation, forecast=est.forecast,
                                   snapshot_every_min=est.snapshot_every_min)
            for line in [] if again else r.warnings:  # what run --check printed: said once
                log.warning("%s", line)
            said = p.resume(conn)
            if again:
                self._resumed.append(said)
            else:
                log.info(said)
            self.pipelines.append(p)
            lo, hi = r.model.bounds(r.gh)
            assert s.latitude is not None and s.longitude is not None
            infos[s.name] = GreenhouseInfo(Place(self.cfg.farm, s.name, s.latitude, s.longitude),
                                           s.inside, s.outside, r.model, lo.tolist(), hi.tolist())
        self.outbox = Outbox(conn, self.cfg.outbox_max, self.cfg.outbox_alarm)
        self.producers = Producers(conn, self.cfg.farm, infos, self.outbox,
                                   diagnosis=self.cfg.diagnosis.enabled)

    def _run(self) -> None:
        conn = open_db(self.cfg.db)
        try:
            self._setup(conn)
            self._ready.set()
            self._loop(conn)
        except BaseException as e:
            self.error = e
            if not isinstance(e, StoreDamaged):  # that one is said where it is met
                log.error("gateway worker stopped: %s: %s", type(e).__name__, e)
        finally:
            self._ready.set()
            close_db(conn)

    def _loop(self, conn) -> None:
        last_status = -STATUS_EVERY
        more = True
        while True:
            stopping = self._stop.is_set()
            if not more and not stopping:
                self.wake.wait(TICK)
                self.wake.clear()
            try:
                more = self._pass(conn)
                if time.monotonic() - last_status >= STATUS_EVERY or stopping:
                    last_status = time.monotonic()
                    self._write_status(conn, stopped=stopping)
            except Exception as e:
                if not self._failed(conn, e):
                    return  # stopping while it fails: the last status row cannot be written
                more = True
                continue
            if self._resumed:  # the first pass that wrote after a failure
                for line in self._resumed:
                    log.info("after the store's failure: %s", line)
                self._resumed = []
            self.outage.ok("worker")
            if stopping:
                return

    def _failed(self, conn, e: Exception) -> bool:
        """A pass whose write failed: the estimators may have stepped minutes whose rows and
        state were not committed, so after the backoff they are made again from the store (as
        a restart would) and step those minutes again. False when the service stops meanwhile;
        raises what is no store fault."""
        counts = self.producers.counts if self.producers is not None else None
        while True:
            delay = self.outage.failed("worker", e)  # a damaged store raises: the service stops
            if delay is None:
                raise e
            if self._stop.wait(delay):
                return False
            try:
                self._setup(conn, again=True)
            except Exception as again:  # the store cannot even be read yet
                e = again
                continue
            if counts is not None and self.producers is not None:  # counted since the start
                self.producers.counts = counts
            return True

    def _pass(self, conn) -> bool:
        """One round; True when an estimator still has minutes to catch up on."""
        assert self.producers is not None
        est = self.cfg.estimator
        made = self.producers.run() if self.publish else 0  # records first: the kit sees it
        if made:  # let the publisher put them before the estimators take the CPU (and the GIL)
            self.wake_publisher(PUBLISH_FIRST_S)
        while aggregate(conn):
            pass
        now = self.clock.now()
        more = False
        for p in self.pipelines:
            rep = p.step_pending(conn, now, est.settle_s, est.max_wait_s, MAX_BATCHES)
            more |= rep.more
            for note in rep.notes:
                log.info(note)
        if self.publish:
            made = self.producers.run()
            made += self.producers.snapshots(now, self.cfg.status_every_s, self._gh_state())
        if made:
            self.wake_publisher(0.0)
        self.passes += 1
        return more

    def _gh_state(self) -> dict[str, dict[str, Any]]:
        assert self.outbox is not None
        pending = self.outbox.pending()
        service = self._service_state()
        out = {}
        for p in self.pipelines:
            s: dict[str, Any] = {"estimatorState": p.state, "outboxPending": pending,
                                 "outboxAlarm": self.outbox.alarm, **service}
            if p.cursor is not None:
                s["estimatedUpTo"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(p.cursor))
            out[p.name] = s
        return out

    def _service_state(self) -> dict[str, Any]:
        """What the status screen shows of the gateway itself, for one that reads it over Zenoh
        (docs/cloud.md, ``status``): uptime [s], store and disk [bytes], Zenoh peers, ingest
        counters, whether the daily diagnosis is on (off: the screen shows no last run), the
        store's latest failure to be written since the start (wall clock; it cannot be
        published while it lasts: the messages wait in the store)."""
        db = self.cfg.db
        size = sum(os.path.getsize(f) for f in (db, f"{db}-wal") if os.path.exists(f))
        try:
            du = shutil.disk_usage(os.path.dirname(os.path.abspath(db)))
            disk = {"diskFree": du.free, "diskTotal": du.total}
        except OSError:
            disk = {}
        extra = self.status_extra()
        z = extra.get("zenoh", {})
        out = {"gatewayUptime": round(time.time() - self.started, 1), "storeSize": size, **disk,
               "zenohPeers": z.get("peers", 0), "zenohRouters": z.get("routers", 0),
               "ingestCounters": extra.get("ingest", {}),
               "diagnosisEnabled": self.cfg.diagnosis.enabled}
        last = self.outage.last
        if last is not None:
            out["storeLastFailure"] = {"cause": last["cause"], "since": _utc(last["since"]),
                                       "until": _utc(last["until"]),
                                       "failedWrites": last["failures"]}
        return out

    def _report_unassigned(self, conn) -> None:
        known = self.cfg.devices()
        for (dev,) in conn.execute("SELECT device_id FROM devices ORDER BY device_id"):
            if dev not in known and dev not in self.unassigned:
                self.unassigned.add(dev)
                log.warning("device %d is in no greenhouse of the config: its records are stored "
                            "(python -m gateway export --device %d) and it is reported as "
                            "unassigned; it is not estimated", dev, dev)

    def _write_status(self, conn, stopped: bool = False) -> None:
        """The status rows; the last, written as the service stops, marks it ``stopped`` [unix s]
        so the screen says so at once rather than after the heartbeat goes stale (20 s)."""
        assert self.producers is not None and self.outbox is not None
        self._report_unassigned(conn)
        pending, oldest = outbox_backlog(conn)
        c = self.producers.counts
        items: dict[str, Any] = {
            "gateway": {"pid": os.getpid(), "started": self.started, "heartbeat": time.time(),
                        "uptime_s": time.time() - self.started, "clock_now": self.clock.now(),
                        "clock_scale": self.clock.scale, "farm": self.cfg.farm,
                        "config": self.cfg.source, "passes": self.passes,
                        "stopped": time.time() if stopped else None},
            "outbox": {"pending": pending, "oldest_t": oldest, "max": self.outbox.max_rows,
                       "alarm_at": self.outbox.alarm_at, "alarm": pending >= self.outbox.alarm_at,
                       "full_rounds": c.full, "made": c.made},
            "greenhouses": {p.name: {"state": p.state, "cursor": p.cursor,
                                     "counters": asdict(p.est.counters)} for p in self.pipelines},
            "devices": {"unassigned": sorted(self.unassigned)},
        }
        items.update(self.status_extra())
        set_status(conn, items, self.clock.now())

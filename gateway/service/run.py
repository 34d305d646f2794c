"""The live gateway on asyncio: ingest (UDP/serial) → store → worker thread (estimators, message
producers) → outbox → publisher thread → Zenoh; history queryable; daily diagnosis subprocess.

Stops cleanly on SIGTERM/SIGINT: transports close, queued records are committed and acknowledged,
the worker makes its last messages, the publisher undeclares, the Zenoh session closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from gateway.ingest.service import IngestConfig, ListenError, Running, serve
from gateway.sdnotify import Notifier
from gateway.service.clock import Clock, make_clock
from gateway.service.diagnosis import DiagnosisScheduler
from gateway.service.resources import GreenhouseResources
from gateway.service.settings import GatewayConfig
from gateway.service.workdir import work_folder
from gateway.service.worker import Worker
from gateway.store import Store, retention
from gateway.store.live import save_greenhouses
from gateway.store.outage import Outage, StoreDamaged

log = logging.getLogger("serra.gateway")
READY = "serra-gateway ready"


def open_store(cfg: GatewayConfig) -> Clock:
    """Create or migrate the store, record the greenhouses, set up the clock (continuing a
    scaled clock's time line across restarts)."""
    store = Store(cfg.db)
    try:
        saved = {n: v for n, v in store.conn.execute(
            "SELECT name, value FROM meta WHERE name LIKE 'clock_%'")}
        c = cfg.clock
        clock, meta = make_clock(c.scale, c.epoch, c.anchor, saved)
        for k, v in meta.items():
            store.set_meta(k, v)
        save_greenhouses(store.conn, [
            {"name": g.name, "farm": cfg.farm, "inside_device": g.inside, "outside_device": g.outside,
             "model": g.model, "config": asdict(g)} for g in cfg.greenhouses], clock.now())
    finally:
        store.close()
    return clock


class Gateway:
    """The running service's parts (tests and the status views read them)."""

    def __init__(self, cfg: GatewayConfig, resources: list[GreenhouseResources]) -> None:
        self.cfg, self.resources = cfg, resources
        self.clock: Clock = open_store(cfg)
        self.session: Any = None
        self.publisher: Any = None
        self.history: Any = None
        self.opener: Any = None  # client mode: opens the session once a router answers
        self.endpoints: list[str] = []
        self.running: Running | None = None
        self.ingest_counters: dict[str, int] = {}
        self.diagnosis: DiagnosisScheduler | None = None
        # one for the service: its parts' write failures are said once, waited out together
        self.outage = Outage(cfg.db, "records not acked, the kits keep them; the estimators and "
                             "the messages wait")
        self.worker = Worker(cfg, resources, self.clock, self._wake_publisher, self._status_extra,
                             publish=cfg.zenoh.enabled, outage=self.outage)

    def _wake_publisher(self, wait: float = 0.0) -> None:
        if self.publisher is not None:
            self.publisher.kick(wait)

    def _status_extra(self) -> dict[str, Any]:
        out: dict[str, Any] = {"ingest": dict(self.ingest_counters), "store": self.outage.status()}
        if self.running is not None:  # kits refused as a whole (a reflashed board), for the screen
            out["refused"] = {str(d): asdict(r) for d, r in self.running.core.refused.items()}
        if self.publisher is not None:
            out["zenoh"] = {"enabled": True, "endpoints": self.endpoints, **asdict(self.publisher.state)}
        elif self.opener is not None:  # no router answered yet: the outbox holds the messages
            out["zenoh"] = {"enabled": True, "mode": "client", "connecting": True,
                            "endpoints": list(self.cfg.zenoh.connect), **asdict(self.opener.state)}
        else:
            out["zenoh"] = {"enabled": False}
        # always written: status rows are replaced, never dropped, so a gateway without the
        # diagnosis (switched off, or not made yet at start) would leave an earlier run's row on
        # the screen, its failure or warnings asking for attention for ever
        out["diagnosis"] = self.diagnosis.status() if self.diagnosis is not None else {}
        return out

    def start_zenoh(self) -> None:
        import zenoh

        from gateway.net.session import SessionOpener
        from gateway.net.zenohcfg import session_entries
        from gateway.publish import zconfig

        z = self.cfg.zenoh
        extra = session_entries(z.connect, z.listen, z.tls, z.retry) | z.extra

        def config() -> zenoh.Config:
            # a peer listens where `listen` says and nowhere else: Zenoh's default for a peer
            # given none (every interface, a random port) is a door on the farm's network that
            # no config asked for, and one no subscriber could find without scanning for it
            return zconfig.build(z.mode, z.connect, z.listen, z.multicast_scouting, extra=extra,
                                 dial_only=True)

        before = zconfig.listening_ports()
        if z.mode == "client":  # open() fails while no router answers: retried in the background
            self.opener = SessionOpener(config, self._attach, z.retry,
                                        what=f"zenoh client of {', '.join(z.connect)}")
            self.opener.start()
            return
        try:
            session = zenoh.open(config())
        except zenoh.ZError as e:  # a bad endpoint or raw key: one line, no traceback
            raise RuntimeError(f"{self.cfg.source}: [zenoh]: cannot open the session: {e}") from None
        self.endpoints = zconfig.resolve_listen(z.listen, before)
        self._attach(session)

    def _attach(self, session: Any) -> None:
        """The session is open: start the publisher and the history queryable on it."""
        from gateway.publish.history import HistoryQueryable
        from gateway.publish.publisher import OutboxPublisher

        z = self.cfg.zenoh
        self.session = session
        self.publisher = OutboxPublisher(
            self.session, self.cfg.db, cache=z.cache, resend_s=z.resend_on_start_s * self.clock.scale,
            clock=self.clock.now, mode=z.mode, max_rows=self.cfg.outbox_max,
            alarm_fraction=self.cfg.outbox_alarm, outage=self.outage)
        self.publisher.start()
        self.history = HistoryQueryable(self.session, self.cfg.db, self.cfg.farm)

    def stop_zenoh(self) -> None:
        if self.opener is not None:
            self.opener.stop()  # no session opens after this
        if self.history is not None:  # its read-only connection first: the publisher's, a
            self.history.close()  # writer's, closes last and SQLite removes the -wal and -shm
        if self.publisher is not None:
            self.publisher.stop()
        if self.session is not None:
            self.session.close()
        self.publisher = self.history = self.session = self.opener = None

    def failure(self) -> BaseException | None:
        if self.worker.error is not None:
            return self.worker.error
        if self.publisher is not None and self.publisher.error is not None:
            return self.publisher.error
        if self.opener is not None and self.opener.error is not None:
            return self.opener.error
        return None


async def run_gateway(cfg: GatewayConfig, resources: list[GreenhouseResources],
                      stop: asyncio.Event, on_ready: Callable[[Gateway], None] | None = None,
                      notify: Notifier | None = None) -> None:
    """Run until ``stop`` is set (or a part fails: re-raised after a clean shutdown). Under
    systemd (``notify``, by default from $NOTIFY_SOCKET) READY=1 follows the ready line, STATUS=
    says what changes, WATCHDOG=1 comes from the supervising loop and STOPPING=1 starts the
    shutdown."""
    notify = notify or Notifier()
    gw = await asyncio.to_thread(Gateway, cfg, resources)
    ready = asyncio.Event()

    def ingest_ready(r: Running) -> None:
        gw.running = r
        ready.set()

    icfg = IngestConfig(
        db=cfg.db, keys=cfg.keys, listen=cfg.listen, serial=cfg.serial, baudrate=cfg.baudrate,
        maintenance_every=cfg.maintenance_s,
        policy=retention.Policy(samples_days=cfg.retention_days, outbox_sent_days=cfg.history_days,
                                estimates_days=cfg.estimates_days,
                                max_db_bytes=int(cfg.max_db_mb * 2**20)),
        clock=gw.clock.now, on_commit=lambda n: gw.worker.wake.set(), outage=gw.outage)
    tasks: list[asyncio.Task] = []
    with work_folder() as tmp:  # removed at the end, or at a later start if this one is killed
        try:
            if cfg.zenoh.enabled:
                await asyncio.to_thread(gw.start_zenoh)
                z = cfg.zenoh
                if not (z.listen or z.connect or z.multicast_scouting):
                    log.warning("zenoh: no listen or connect endpoint and no scouting: this "
                                "gateway listens nowhere and dials no one, messages wait in the "
                                'outbox; set [zenoh] listen (e.g. ["tcp/0.0.0.0:7447"], where '
                                "subscribers connect) or connect (a router, the cloud's peer)")
            await asyncio.to_thread(gw.worker.start)
            ingest = asyncio.create_task(serve(icfg, ingest_ready), name="ingest")
            tasks.append(ingest)
            waiter = asyncio.create_task(ready.wait())
            await asyncio.wait({ingest, waiter}, return_when=asyncio.FIRST_COMPLETED)
            waiter.cancel()
            if ingest.done():
                _ingest_failed(ingest, cfg)
            if cfg.diagnosis.enabled:  # it reads its kept runs from the store: off the loop
                gw.diagnosis = await asyncio.to_thread(
                    DiagnosisScheduler, cfg, resources, gw.clock.now, tmp, gw.worker.wake.set,
                    gw.outage)
                tasks.append(asyncio.create_task(gw.diagnosis.run_forever(), name="diagnosis"))
            _announce(gw)
            notify.ready(systemd_status(gw))
            if on_ready is not None:
                on_ready(gw)
            await _supervise(gw, tasks, stop, notify)
        finally:
            # a failing part's shutdown too: it may wait a minute for the worker, with no
            # watchdog pings; the exit status still decides whether systemd restarts it
            notify.stopping()
            await _shutdown(gw, tasks)


def _ingest_failed(ingest: asyncio.Task, cfg: GatewayConfig) -> None:
    """Raise why ingest could not start, naming what it was to listen on."""
    try:
        ingest.result()
    except ListenError:
        raise  # already one line naming the address and the reason
    except OSError as e:
        where = [f"udp {cfg.listen[0]}:{cfg.listen[1]}"] if cfg.listen else []
        where += [f"serial {cfg.serial}"] if cfg.serial else []
        raise OSError(f"ingest cannot start on {' and '.join(where)}: {e.strerror or e}") from None
    raise RuntimeError("ingest stopped at start")


def _announce(gw: Gateway) -> None:
    assert gw.running is not None
    parts = [READY]
    if gw.running.udp_address:
        parts.append(f"udp {gw.running.udp_address[0]}:{gw.running.udp_address[1]}")
    if gw.cfg.serial:
        parts.append(f"serial {gw.cfg.serial}")
    parts.append("zenoh " + (",".join(gw.endpoints) or "-") if gw.cfg.zenoh.enabled else "zenoh off")
    print(" ".join(parts), flush=True)
    log.info("farm %s: %d greenhouse(s) %s; store %s", gw.cfg.farm, len(gw.cfg.greenhouses),
             ", ".join(f"{g.name} (kits {g.inside}/{g.outside}, {g.model})" for g in gw.cfg.greenhouses),
             gw.cfg.db)


def systemd_status(gw: Gateway) -> str:
    """The line ``systemctl status`` shows (STATUS=): a store that cannot be written, first;
    greenhouses, kits, ports, Zenoh's link."""
    parts = [gw.outage.status_line()] if gw.outage.failing else []
    parts.append(f"{_n(len(gw.cfg.greenhouses), 'greenhouse')}, {_n(len(gw.cfg.devices()), 'kit')}")
    if gw.running is not None and gw.running.udp_address:
        parts.append(f"udp {gw.running.udp_address[0]}:{gw.running.udp_address[1]}")
    if gw.cfg.serial:
        parts.append(f"serial {gw.cfg.serial}")
    parts.append(_zenoh_status(gw))
    return "; ".join(parts)


def _zenoh_status(gw: Gateway) -> str:
    if not gw.cfg.zenoh.enabled:
        return "zenoh off"
    if gw.publisher is not None:
        s = gw.publisher.state
        if s.routers or s.peers:
            return f"zenoh linked ({_n(s.routers, 'router')}, {_n(s.peers, 'peer')})"
        return "zenoh open, not linked yet"
    if gw.opener is not None:
        o = gw.opener.state
        return f"zenoh connecting to {', '.join(gw.cfg.zenoh.connect)} (attempt {o.attempts})"
    return "zenoh not open"


def _n(count: int, word: str) -> str:
    return f"{count} {word}{'s' * (count != 1)}"


async def _supervise(gw: Gateway, tasks: list[asyncio.Task], stop: asyncio.Event,
                     notify: Notifier) -> None:
    while not stop.is_set():
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 1.0)
        for t in tasks:
            if t.done():
                t.result()  # a task that ended by itself failed: raise it
        err = gw.failure()
        if isinstance(err, StoreDamaged):
            raise err
        if err is not None:
            raise RuntimeError(f"a gateway part stopped: {type(err).__name__}: {err}")
        if gw.running is not None:
            gw.ingest_counters = gw.running.core.counters.snapshot()
        # here, where every part was just checked: the event loop (ingest, acks) turns; a slow
        # worker or publisher does not hold it back (WatchdogSec= in serra-gateway.service)
        notify.watchdog()
        notify.status(systemd_status(gw))


async def _shutdown(gw: Gateway, tasks: list[asyncio.Task]) -> None:
    if gw.diagnosis is not None:
        gw.diagnosis.kill()
    for t in reversed(tasks):  # the diagnosis first, then ingest (commits and acks what it holds)
        t.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await t
    if gw.running is not None:
        gw.ingest_counters = gw.running.core.counters.snapshot()
    await asyncio.to_thread(gw.worker.stop)
    await asyncio.to_thread(gw.stop_zenoh)
    log.info("gateway stopped; ingest counters %s", gw.ingest_counters)

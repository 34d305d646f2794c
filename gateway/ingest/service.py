"""The ingest service: UDP and/or serial in, SQLite out, periodic aggregation and retention.

    python -m gateway.ingest.service --db serra.db --keys keys.txt --listen 127.0.0.1:5683
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import logging
import os
import signal
import socket
import sqlite3
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.cli.helpformat import ArgumentParser
from gateway.ingest.core import IngestCore
from gateway.ingest.keys_watch import KeysWatch
from gateway.ingest.udp import UdpServer
from gateway.sdnotify import Notifier
from gateway.store import Store, StoreError, aggregate, retention
from gateway.store.capacity import CapacityWatch
from gateway.store.keys import KeyFileError, load_keys
from gateway.store.outage import Outage, StoreCorrupt, StoreDamaged, damaged, exit_status

if TYPE_CHECKING:
    from gateway.ingest.serial import SerialTransport

log = logging.getLogger("serra.ingest")

DEFAULT_PORT = 5683


@dataclass
class IngestConfig:
    db: Path
    keys: Path
    listen: tuple[str, int] | None = ("0.0.0.0", DEFAULT_PORT)
    serial: str | None = None
    baudrate: int = 115200
    batch_delay: float = 0.0  # extra wait to grow a batch (commits are already grouped)
    max_pending: int = 50_000
    maintenance_every: float = 10.0  # aggregation, retention, capacity alarms, keys file [s]
    stats_every: float = 60.0
    policy: retention.Policy = field(default_factory=retention.Policy)
    # The live gateway (gateway/service/run.py): its clock and a callback after each durable batch.
    clock: Callable[[], float] = time.time
    on_commit: Callable[[int], None] | None = None
    # Where a store that cannot be written is said (the live gateway shares one with its parts).
    outage: Outage | None = None


class ListenError(OSError):
    """A transport that cannot be opened, said in one line: address (or port) and reason."""


def parse_hostport(text: str) -> tuple[str, int]:
    """ADDRESS:PORT with a numeric address (IPv6 in brackets); never a DNS look-up."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    if not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} of {text!r} is outside 0..65535")
    host = host.strip("[]")
    if host == "localhost":
        host = "127.0.0.1"
    try:
        ipaddress.ip_address(host.partition("%")[0] or "0.0.0.0")  # fe80::1%eth0: zone kept
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{host!r} is not an IP address: give the address to listen on, e.g. "
            f"0.0.0.0:{port} (all interfaces) or 192.168.4.1:{port}; host names are not "
            "resolved") from None
    return host or "0.0.0.0", int(port)


def _where(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _open_udp(core: IngestCore, host: str, port: int) -> UdpServer:
    try:
        return UdpServer(core, host, port)
    except socket.gaierror:
        raise ListenError(f"cannot listen on {_where(host, port)}: not an IP address (host "
                          "names are not resolved)") from None
    except OSError as e:
        why = (e.strerror or str(e)).lower()
        raise ListenError(f"cannot listen on {_where(host, port)}: {why}") from None


def _maintenance(store: Store, policy: retention.Policy, now: float, watch: CapacityWatch
                 ) -> None:
    # measured first: a full disk fails the writes below, and is then what most needs saying
    retention.watch_capacity(watch, store.path, policy)
    aggregate.aggregate(store.conn)
    retention.apply(store.conn, policy, now)


@dataclass
class Running:
    """Handed to serve()'s on_ready callback: live objects for status views and tests."""

    core: IngestCore
    store: Store
    udp_address: tuple[str, int] | None


async def serve(config: IngestConfig,
                on_ready: Callable[[Running], None] | None = None) -> None:
    """Run until cancelled. Prints one 'listening' line per transport (tests read the port)."""
    watch = KeysWatch(config.keys)
    capacity = CapacityWatch()  # its alarms said once, not every round
    keys = load_keys(config.keys)
    if not keys:
        log.warning("keys file %s lists no device: every packet will be refused as "
                    "unknown_device. Add one with: python -m gateway keys add DEVICE_ID --keys "
                    "%s (read again within %g s, no restart)", config.keys, config.keys,
                    config.maintenance_every)
    store = Store(config.db)
    core = IngestCore(store, keys, max_pending=config.max_pending,
                      batch_delay=config.batch_delay, keys_path=config.keys,
                      clock=config.clock, on_commit=config.on_commit, outage=config.outage)
    transports: list = []
    started = False
    try:
        if config.listen is not None:
            udp = _open_udp(core, *config.listen)
            udp.start()
            transports.append(udp)
            print(f"serra-ingest listening udp {udp.address[0]}:{udp.address[1]}", flush=True)
        if config.serial:
            transports.append(_open_serial(core, config.serial, config.baudrate))
            print(f"serra-ingest listening serial {config.serial}", flush=True)
        started = True
        log.info("%d device keys, store %s", len(keys), config.db)
        if on_ready is not None:
            on_ready(Running(core, store, transports[0].address if config.listen else None))
        writer = asyncio.create_task(core.run_writer())
        loop = asyncio.get_running_loop()
        t_stats = loop.time()
        while True:
            await asyncio.wait({writer}, timeout=config.maintenance_every)
            if writer.done():
                writer.result()  # surface a writer crash (a damaged store: StoreDamaged)
            await _maintain(core, store, watch, config, capacity)
            if loop.time() - t_stats >= config.stats_every:
                t_stats = loop.time()
                log.info("ingest counters %s%s", core.counters.snapshot(), _refused(core))
    finally:
        # nothing new taken in, what is queued or held committed and acked, then the transports
        # closed: closed first, the drain's acks failed ("ack ... failed") and the kits resent
        # records already stored to the next start
        for t in transports:
            t.pause()
        with contextlib.suppress(Exception):
            await core.drain()
        for t in transports:
            t.close()
        core.close()
        store.close()
        if started:
            log.info("ingest stopped; counters %s%s", core.counters.snapshot(), _refused(core))


async def _maintain(core: IngestCore, store: Store, watch: KeysWatch,
                    config: IngestConfig, capacity: CapacityWatch) -> None:
    """A maintenance round and the keys file read again if it changed. A store that cannot be
    written skips the round (the outage is said once; the next round tries again)."""
    try:
        await core.run_in_store_thread(_maintenance, store, config.policy, config.clock(),
                                       capacity)
        core.outage.ok("maintenance")
    except Exception as e:
        if core.outage.failed("maintenance", e) is None:  # not the store's: the service stops
            raise
    stamp = watch.stamp
    new_keys = watch.changed_keys()
    if new_keys is None:
        return
    try:
        changed = await core.reload_keys(new_keys)
    except Exception as e:  # the new keys' boot bases are written to the store
        if core.outage.failed("maintenance", e) is None:
            raise
        watch.stamp = stamp  # read again next round
        return
    log.info("keys file %s read again: %s (%d devices)", config.keys, changed, len(new_keys))


def _open_serial(core: IngestCore, url: str, baudrate: int) -> SerialTransport:
    from gateway.ingest.serial import SerialTransport

    try:
        ser = SerialTransport(core, url, baudrate)
    except (OSError, ValueError) as e:  # serial.SerialException is an OSError
        inner = e.__context__ if isinstance(e.__context__, OSError) else e
        why = (getattr(inner, "strerror", None) or str(e)).lower()
        raise ListenError(f"cannot open serial port {url}: {why}") from None
    ser.start()
    return ser


def _refused(core: IngestCore) -> str:
    if not core.refused:
        return ""
    return "; refused devices: " + ", ".join(
        f"{r.device_id} ({r.reason} x{r.count}, recover: {r.recovery})"
        for r in core.refused.values())


def bounded(kind: type, lo: float, hi: float | None = None) -> Callable[[str], float]:
    """argparse type: a finite number of ``kind`` in [lo, hi], the bounds of the same keys
    in gateway.toml (a negative retention would delete every sample as it arrives)."""

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            what = "a whole number" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not (value >= lo and (hi is None or value <= hi)):  # NaN fails too
            span = f"at least {lo:g}" if hi is None else f"between {lo:g} and {hi:g}"
            raise argparse.ArgumentTypeError(f"must be {span}, got {text!r}")
        return value

    return parse


def build_parser(prog: str = "python -m gateway.ingest.service") -> argparse.ArgumentParser:
    ap = ArgumentParser(
        prog=prog,
        description="Serra ingest: kit packets in over UDP and/or a serial port, validated, "
        "stored durably in SQLite (WAL), then acknowledged. See docs/wire-format.md.",
        epilog="example: %(prog)s --db serra.db --keys keys.txt --listen 0.0.0.0:5683")
    ap.add_argument("--db", type=Path, required=True, metavar="serra.db",
                    help="SQLite store (created if absent; its folder must exist)")
    ap.add_argument("--keys", type=Path, required=True, metavar="keys.txt",
                    help="device keys file, mode 600: '<device_id> <hex key>' per line "
                         "(python -m gateway keys)")
    ap.add_argument("--listen", type=parse_hostport, default=None, metavar="ADDRESS:PORT",
                    help=f"UDP address (numeric, never resolved) and port (default "
                         f"0.0.0.0:{DEFAULT_PORT} unless --serial only)")
    ap.add_argument("--serial", default=None, metavar="URL",
                    help="pyserial URL of a board on USB, e.g. /dev/ttyUSB0 or loop://")
    ap.add_argument("--baudrate", type=bounded(int, 300, 4_000_000), default=115200,
                    metavar="BAUD", help="serial speed [bit s-1] (default %(default)s)")
    ap.add_argument("--retention-days", type=bounded(float, retention.MIN_DAYS), metavar="DAYS",
                    default=retention.Policy.samples_days,
                    help=f"keep raw samples this many days, at least {retention.MIN_DAYS:g} (minute "
                         "aggregates are kept longer; default %(default)g)")
    ap.add_argument("--max-db-mb", type=bounded(float, retention.MIN_DB_MB), metavar="MB",
                    default=retention.Policy.max_db_bytes / 2**20,
                    help="alarm when the database reaches 80 %% of this size [MiB] "
                         "(default %(default)g)")
    ap.add_argument("--batch-delay", type=bounded(float, 0.0), default=0.0, metavar="S",
                    help="seconds to wait for more records before a commit (fewer SD-card "
                         "writes; acks are delayed as much; default %(default)g)")
    ap.add_argument("--maintenance-every", type=float, default=10.0, help=argparse.SUPPRESS)
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    ap.add_argument("-q", "--quiet", action="store_true",  # python -m gateway -q ingest ...
                    help="nothing to silence: the service shows no progress (taken as the "
                    "gateway's other commands take it)")
    return ap


async def _run_until_signal(cfg: IngestConfig) -> None:
    """serve() until SIGTERM/SIGINT; under systemd (Type=notify, $NOTIFY_SOCKET) READY=1 once
    every transport is open, STOPPING=1 at the signal."""
    notify = Notifier()
    serving = ""

    def ready(r: Running) -> None:
        nonlocal serving
        where = [f"udp {_where(*r.udp_address)}"] if r.udp_address else []
        serving = ", ".join(where + ([f"serial {cfg.serial}"] if cfg.serial else []))
        notify.ready(serving)

    def store_changed() -> None:  # STATUS= says a failing store until it is back
        notify.status("; ".join(filter(None, (outage.status_line(), serving))))

    outage = cfg.outage = Outage(cfg.db, "records not acked, the kits keep them", store_changed)

    def stop() -> None:
        notify.stopping()
        task.cancel()

    task = asyncio.ensure_future(serve(cfg, ready))
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop)
    with contextlib.suppress(asyncio.CancelledError):
        await task


def main(argv: list[str] | None = None, prog: str = "python -m gateway.ingest.service") -> int:
    args = build_parser(prog).parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    listen = args.listen
    if listen is None and not args.serial:
        listen = ("0.0.0.0", DEFAULT_PORT)
    cfg = IngestConfig(
        db=args.db, keys=args.keys, listen=listen, serial=args.serial, baudrate=args.baudrate,
        maintenance_every=args.maintenance_every, batch_delay=args.batch_delay,
        policy=retention.Policy(samples_days=args.retention_days,
                                max_db_bytes=int(args.max_db_mb * 2**20)))
    # The keys file is the service's configuration: a wrong one exits 78 (EX_CONFIG), which the
    # unit's RestartPreventExitStatus= keeps from restarting; the store, the address and the serial
    # port exit 2 (a disk, a port or a USB cable can come right by themselves: systemd retries);
    # a damaged store file exits 65 (EX_DAMAGED), not restarted either: it does not mend itself.
    try:
        load_keys(cfg.keys)  # fail early with a clear message
    except KeyFileError as e:
        print(f"error: {e}", file=sys.stderr)
        return os.EX_CONFIG
    except OSError as e:
        print(f"error: {cfg.keys}: cannot read the keys file: {e.strerror or e} (make it with "
              f"python -m gateway keys add DEVICE_ID --keys {cfg.keys})", file=sys.stderr)
        return os.EX_CONFIG
    try:
        Store(cfg.db).close()
    except StoreError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (sqlite3.Error, RuntimeError, OSError) as e:
        bad = damaged(e, cfg.db)  # a damaged file: not restarted (EX_DAMAGED)
        if isinstance(bad, StoreCorrupt):
            print(f"error: {bad}", file=sys.stderr)
            return exit_status(bad)
        print(f"error: cannot open the store {cfg.db}: {e}", file=sys.stderr)
        return 2

    try:
        asyncio.run(_run_until_signal(cfg))
    except KeyFileError as e:
        print(f"error: {e}", file=sys.stderr)
        return os.EX_CONFIG
    except ListenError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except StoreDamaged as e:  # said in the log
        return exit_status(e)
    except sqlite3.Error as e:  # the start's first writes (boot bases): as the open's, exit 2
        bad = damaged(e, cfg.db)
        if isinstance(bad, StoreCorrupt):
            print(f"error: {bad}", file=sys.stderr)
            return exit_status(bad)
        print(f"error: cannot write the store {cfg.db}: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``python -m gateway subscribe``: the cloud side over Zenoh (docs/cloud.md)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from gateway.cli import CliError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "subscribe",
        help="play the cloud: store what the gateway publishes (dropping repeats), export kit CSVs",
        description="Subscribe to Serra messages over Zenoh and store each one once in SQLite "
        "(repeats dropped by idempotency key); recover what was missed from the publishers' "
        "caches. With --export, write a kit CSV per greenhouse from the stored measurements "
        "(without --connect: export only).",
        epilog="example: python -m gateway subscribe --connect tcp/192.168.1.20:7447 --db cloud.db; "
        "python -m gateway subscribe --db cloud.db --export csv/")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="Zenoh endpoint of a gateway or router, e.g. tcp/127.0.0.1:7447 (repeatable)")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="also listen for gateways on this endpoint (peer mode)")
    p.add_argument("--mode", choices=("peer", "client"), default="peer", help="Zenoh mode (peer)")
    p.add_argument("--key", default="serra/**", help="key expression to subscribe to (serra/**)")
    p.add_argument("--db", required=True, type=Path, help="the cloud store (SQLite, created if absent)")
    p.add_argument("--export", type=Path, metavar="DIR",
                   help="write <farm>-<greenhouse>.csv kit CSVs here (at exit when subscribed)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=run)


def _export(store, folder: Path) -> None:
    from gateway.cloud.subscriber import export_kit_csv

    folder.mkdir(parents=True, exist_ok=True)
    ghs = store.greenhouses()
    if not ghs:
        print(f"{store.path}: no measurement stored yet: nothing to export", file=sys.stderr)
    for farm, gh in ghs:
        out = folder / f"{farm}-{gh}.csv"
        n = export_kit_csv(store, farm, gh, out)
        print(f"wrote {out}: {n} minutes")


def run(args: argparse.Namespace) -> int:
    import sqlite3

    from gateway.cloud.store import SqliteCloudStore
    from gateway.cloud.subscriber import Subscriber

    if not args.connect and not args.listen and not args.export:
        raise CliError("give --connect ENDPOINT (or --listen) to subscribe, or --export DIR")
    try:
        store = SqliteCloudStore(args.db)
    except sqlite3.Error as e:
        raise CliError(f"{args.db}: cannot open the cloud store: {e}") from None
    try:
        if args.connect or args.listen:
            _subscribe(args, store, Subscriber)
        if args.export:
            _export(store, args.export)
    finally:
        store.close()
    return 0


def _subscribe(args: argparse.Namespace, store, subscriber_cls) -> None:
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    sub = subscriber_cls(store, args.connect, args.key, args.mode, args.listen)
    try:
        sub.start()
    except Exception as e:
        sub.stop()
        raise CliError(f"cannot open the Zenoh session: {e}") from None
    print(f"serra-subscribe ready {args.key} on {', '.join(args.connect + args.listen)}", flush=True)
    t0 = time.monotonic()
    last = t0
    try:
        while not stop.wait(0.5):
            if args.duration is not None and time.monotonic() - t0 >= args.duration:
                break
            if sub.error is not None:
                raise CliError(f"{args.db}: {sub.error}")
            if time.monotonic() - last >= 10:
                last = time.monotonic()
                print(f"subscribe: {sub.stats}", file=sys.stderr, flush=True)
    finally:
        sub.stop()
        print(f"subscribe stopped: {sub.stats}; {store.count()} messages stored", file=sys.stderr,
              flush=True)

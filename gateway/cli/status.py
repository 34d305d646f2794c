"""``python -m gateway status``: the on-site status screen (docs/gateway.md, "Status screen")."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gateway.cli import CliError

DEFAULT_CONFIG = Path("/etc/serra/gateway.toml")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "status",
        help="the status screen: greenhouses, kits and the gateway, from the store or over Zenoh",
        description="Show what the gateway knows, refreshed every few seconds, on any terminal of "
        "80×24 or more (over SSH too): per greenhouse the latest inside and outside readings with "
        "24-h sparklines, measured vs predicted inside temperature with the forecasts and their "
        "error beside persistence, the model parameters inside their bounds, the ventilation "
        "estimate and the latest findings; per kit the last record, records, rejected packets by "
        "reason, the board's boot counter and each channel's status; the gateway's Zenoh link, "
        "outbox backlog and alarm, disk use and uptime. Keys: 1/2/3 (or g/k/w) switch panel, "
        "tab the next one, ←/→ the greenhouse, ↑/↓ scroll, r refresh, q quit. "
        "It never writes: the store is opened read-only; over Zenoh it only asks the gateway's "
        "history (it never subscribes, so it cannot drain a backlog meant for the cloud).",
        epilog="examples: sudo -u serra python -m gateway status --config /etc/serra/gateway.toml; "
        "python -m gateway status --db serra.db --once (a plain snapshot for scripts and cron: "
        "exit status 1 when something needs attention); "
        "python -m gateway status --connect tcp/192.168.1.20:7447 (from another machine)")
    where = p.add_mutually_exclusive_group()
    # metavars short enough for the group's usage to fit 80 columns (argparse never splits it)
    where.add_argument("--db", type=Path, metavar="DB",
                       help="the gateway's store, e.g. serra.db (read-only)")
    where.add_argument("--config", type=Path, metavar="TOML",
                       help=f"read the store the gateway config names (default: {DEFAULT_CONFIG} "
                       "when neither --db nor --connect is given)")
    where.add_argument("--connect", action="append", metavar="ENDPOINT",
                       help="ask a gateway (or a router) over Zenoh, e.g. tcp/192.168.1.20:7447 "
                       "(repeatable)")
    p.add_argument("--mode", choices=("peer", "client"), default="peer",
                   help="Zenoh mode with --connect (client: through a router; default peer)")
    p.add_argument("--farm", default="*", help="with --connect: only this farm (default: any)")
    p.add_argument("--once", action="store_true",
                   help="print one plain snapshot of every panel and exit (also when stdout is "
                   "not a terminal); exit status 1 when something needs attention")
    p.add_argument("--panel", choices=("greenhouse", "kits", "gateway"), default="greenhouse",
                   help="the panel shown first (default greenhouse)")
    p.add_argument("--greenhouse", metavar="NAME", help="the greenhouse shown first")
    p.add_argument("--interval", type=float, default=2.0, metavar="S",
                   help="time between refreshes [s] (default 2)")
    p.set_defaults(func=run)


def open_source(args: argparse.Namespace):
    """The snapshot source the arguments name (CliError with the reason otherwise)."""
    from gateway.store import StoreError

    if args.connect:
        import re

        from gateway.status.zenoh_source import ZenohSource

        for endpoint in args.connect:  # the form gateway.toml's zenoh.listen takes, said in words
            if not re.match(r"^[a-z0-9]+/.+", endpoint):  # (Zenoh's own is a Rust debug dump)
                raise CliError(f"--connect {endpoint!r}: expected PROTOCOL/ADDRESS, e.g. "
                               f"tcp/192.168.1.20:7447")
        try:
            return ZenohSource(args.connect, mode=args.mode, farm=args.farm)
        except Exception as e:
            raise CliError(f"cannot open a Zenoh session to {', '.join(args.connect)}: {e}") from None
    db = args.db
    if db is None:
        config = args.config or DEFAULT_CONFIG
        db = _db_from_config(config, explicit=args.config is not None)
        if not db.exists():
            raise CliError(f"{db}: no such store (the gateway.db of {config}; the gateway "
                           f"creates it when it first runs)")
    from gateway.status.store_source import StoreSource

    try:
        return StoreSource(db)
    except StoreError as e:
        raise CliError(str(e)) from None


def _db_from_config(path: Path, explicit: bool) -> Path:
    from gateway.tomlfile import read_toml

    if not path.exists():
        if explicit:
            raise CliError(f"{path}: no such config")
        raise CliError(f"give --db serra.db, --config gateway.toml or --connect ENDPOINT "
                       f"({path} does not exist)")
    raw = read_toml(path, CliError, "gateway config")
    table = raw.get("gateway")
    if not isinstance(table, dict):  # worded as the service's own config check words it
        raise CliError(f"{path}: gateway: missing (required): a [gateway] table with db = "
                       f"\"serra.db\" (is this the gateway's config?)")
    db = table.get("db")
    if db is None:
        raise CliError(f"{path}: gateway.db: missing (required)")
    if not isinstance(db, str) or not db:
        raise CliError(f"{path}: gateway.db: must be a path in quotes, got {db!r}")
    p = Path(db).expanduser()
    return p if p.is_absolute() else path.resolve().parent / p


def run(args: argparse.Namespace) -> int:
    if args.interval <= 0:
        raise CliError("--interval must be positive")
    source = open_source(args)
    try:
        if args.once or not sys.stdout.isatty():
            return _once(source)
        from gateway.status.app import StatusApp

        StatusApp(source, args.interval, args.panel, args.greenhouse).run()
        return 0
    finally:
        source.close()


def _once(source) -> int:
    from gateway.status.render import plain
    from gateway.status.snapshot import attention

    snap = source.snapshot()
    todo = attention(snap)
    head = "".join(f"ATTENTION: {a}\n" for a in todo)
    sys.stdout.write(head + ("\n" if head else "") + plain(snap))
    sys.stdout.flush()
    return 1 if todo else 0

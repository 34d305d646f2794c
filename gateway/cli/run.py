"""``python -m gateway run --config gateway.toml``: the live gateway service (docs/gateway.md)."""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sqlite3
import sys
from pathlib import Path

from gateway.cli import ConfigFileError

_PRIORITY = {"DEBUG": 7, "INFO": 6, "WARNING": 4, "ERROR": 3, "CRITICAL": 2}


class JournalFormatter(logging.Formatter):
    """One line per event. Under systemd (``$JOURNAL_STREAM`` set) each line starts with its
    syslog priority (``<4>``) and has no time stamp: journald adds both."""

    def __init__(self) -> None:
        self.journal = bool(os.environ.get("JOURNAL_STREAM"))
        fmt = "%(levelname)s %(name)s: %(message)s"
        super().__init__(fmt if self.journal else "%(asctime)s " + fmt)

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record).replace("\n", " | ")  # one event, one line
        return f"<{_PRIORITY.get(record.levelname, 6)}>{text}" if self.journal else text


def setup_logging(level: str) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournalFormatter())
    logging.basicConfig(level=level.upper(), handlers=[handler], force=True)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="run the live gateway: kits → estimator → store → Zenoh (docs/gateway.md)",
        description="Run the live gateway service: ingest kit records (UDP/serial), run each "
        "greenhouse's online estimator every minute with causal forecasts, store everything, "
        "publish over Zenoh with store-and-forward, answer history queries, and diagnose daily. "
        "Stops cleanly on SIGTERM/SIGINT.",
        epilog="example: python -m gateway run --config /etc/serra/gateway.toml "
        "(documented example: images/gateway/gateway.toml)")
    p.add_argument("--config", required=True, type=Path, metavar="gateway.toml",
                   help="the gateway config (TOML)")
    p.add_argument("--check", action="store_true",
                   help="validate the config and what it names (keys, greenhouses, parameters, "
                   "the store's folder), then exit")
    p.add_argument("--log-level", choices=("debug", "info", "warning", "error"),
                   help="override [gateway] log_level")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gateway.service.config import ConfigError, load_config
    from gateway.service.resources import prepare

    try:
        cfg = load_config(args.config)
        resources = prepare(cfg)
    except ConfigError as e:  # exit 78 (EX_CONFIG): systemd does not restart the unit
        raise ConfigFileError(str(e)) from None
    setup_logging(args.log_level or ("debug" if args.verbose else cfg.log_level))
    if args.check:  # the service logs the same warnings once at start (worker.py)
        for line in (w for r in resources for w in r.warnings):
            print(f"warning: {line}", file=sys.stderr)
        print(f"{args.config}: ok: farm {cfg.farm}, {len(cfg.greenhouses)} greenhouse(s), "
              f"devices {', '.join(map(str, sorted(cfg.devices())))}")
        return 0
    return asyncio.run(_main(cfg, resources))


async def _main(cfg, resources) -> int:
    from gateway.ingest.service import ListenError
    from gateway.service.config import ConfigError
    from gateway.service.run import run_gateway
    from gateway.store.outage import StoreCorrupt, StoreDamaged, damaged, exit_status

    log = logging.getLogger("serra.gateway")
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    try:
        await run_gateway(cfg, resources, stop)
    except ConfigError as e:  # a config fault only the start finds: as run --check's, exit 78
        log.error("%s", e)
        return os.EX_CONFIG
    except ListenError as e:  # exit 2, not 78: a port held or an address not up yet may pass
        log.error("%s", e)
        return 2
    except StoreDamaged as e:  # a damaged or deleted store: said where it was met
        return exit_status(e)
    except (OSError, sqlite3.Error, RuntimeError) as e:  # expected faults: one line, no traceback
        bad = damaged(e, cfg.db)  # the start met a damaged file: not restarted (EX_DAMAGED)
        if isinstance(bad, StoreCorrupt):
            log.error("%s", bad)
            return exit_status(bad)
        log.error("%s", e)
        return 1
    return 0

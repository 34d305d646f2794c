"""``python -m gateway subscribe``: the cloud side over Zenoh (docs/cloud.md, docs/fleet.md)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from gateway.cli import CliError, ConfigFileError
from gateway.cli.common import check_output, writing
from gateway.cli.helpformat import ExamplesHelpFormatter

EPILOG = """\
examples:
  python -m gateway subscribe --connect tcp/192.168.1.20:7447 --db cloud.db
  python -m gateway subscribe --db cloud.db --export csv/          # export only
  python -m gateway subscribe --mode client \\
      --connect tls/cloud-1.example.org:7447 --tls-ca certs/ca.pem \\
      --tls-cert certs/client-cloud-store.pem \\
      --tls-key certs/client-cloud-store.key --farm farm-a --farm farm-b \\
      --dsn 'host=/run/postgresql dbname=serra user=serra' --history
  # the same, from a file:
  python -m gateway subscribe --config /etc/serra/subscriber.toml

Behind the routers' access control, subscribe per farm (--farm, or farms/access in the file):
a gateway is only told of subscriptions inside its own farm. Options given here override the
file. In client mode the subscriber waits for a router (retried) and prints its ready line once
subscribed. Keep a DSN's password out of the command line: use ~/.pgpass or PGPASSFILE.

While the store refuses writes (PostgreSQL down) what arrives is held and retried; the counters
line on stderr (every 10 s) shows received ahead of stored. Exit status 78 (EX_CONFIG): a wrong
setting, file, certificate or DSN syntax (one line; its systemd unit does not restart on it).
Exit status 2: PostgreSQL not answering or refusing at start, wrong password included (one line
naming the DSN without its password; the unit restarts it), or stopped while the store still
refused messages (how many were not stored; the next start's catch-up asks the gateways' history
for them). Under systemd (NOTIFY_SOCKET) it says READY=1 after its ready line (docs/cloud.md).
"""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "subscribe",
        help="play the cloud: store what the gateways publish (dropping repeats), export kit CSVs",
        description=(
            "Subscribe to Serra messages over Zenoh and store each one once, in SQLite "
            "(the default) or PostgreSQL (--dsn); repeats are dropped by idempotency key, and what "
            "was missed is recovered from the publishers' caches. With --history, answer history "
            "queries for the farms from the store. With --export, write a kit CSV per greenhouse "
            "from the stored measurements (without an endpoint: export only)."),
        epilog=EPILOG, formatter_class=ExamplesHelpFormatter)
    p.add_argument("--config", type=Path, metavar="SUBSCRIBER.toml",
                   help="settings file ([subscribe], [tls]; docs/examples/subscriber.toml)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="Zenoh endpoint of a gateway or router, e.g. tcp/127.0.0.1:7447 (repeatable; "
                   "in client mode the routers to fail over between)")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="also listen for gateways on this endpoint (peer mode)")
    p.add_argument("--mode", choices=("peer", "client"), help="Zenoh mode (default peer)")
    p.add_argument("--key", action="append", default=[], metavar="KEYEXPR",
                   help="key expression to subscribe to (repeatable; default serra/**, or one per --farm)")
    p.add_argument("--farm", action="append", default=[], metavar="FARM",
                   help="subscribe to serra/FARM/** (repeatable); also the farms --history answers for")
    p.add_argument("--db", type=Path, metavar="cloud.db",
                   help="SQLite cloud store (created if absent)")
    p.add_argument("--dsn", metavar="DSN",
                   help="PostgreSQL cloud store instead (needs the cloud extra, psycopg 3)")
    p.add_argument("--schema", metavar="NAME", help="PostgreSQL schema (default serra)")
    p.add_argument("--history", action="store_true",
                   help="answer history queries for the farms from the store")
    p.add_argument("--tls-ca", type=Path, metavar="PEM", help="the fleet CA (tls/ endpoints)")
    p.add_argument("--tls-cert", type=Path, metavar="PEM", help="this subscriber's certificate")
    p.add_argument("--tls-key", type=Path, metavar="KEY", help="its private key (mode 0600)")
    p.add_argument("--export", type=Path, metavar="DIR",
                   help="write <farm>-<greenhouse>.csv kit CSVs here (at exit when subscribed)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="stop after this long [s], > 0 (default: run until stopped)")
    p.set_defaults(func=run)


def settings(args: argparse.Namespace):
    """The file's settings (if any) with the command line's on top, checked."""
    from gateway.cloud.settings import SubscribeSettings, load_settings, with_overrides
    from gateway.net.certs import CertError
    from gateway.net.tomlcheck import ConfigError
    from gateway.net.zenohcfg import TlsFiles

    try:
        s = load_settings(args.config) if args.config else SubscribeSettings()
        tls = None
        if args.tls_ca or args.tls_cert or args.tls_key:
            if args.tls_ca is None:
                raise ConfigError("--tls-cert/--tls-key need --tls-ca (the fleet CA)")
            tls = TlsFiles(args.tls_ca, args.tls_cert, args.tls_key, mutual=args.tls_cert is not None)
            tls.check("--tls")
        return with_overrides(s, mode=args.mode, connect=tuple(args.connect),
                              listen=tuple(args.listen), keys=tuple(args.key), farms=tuple(args.farm),
                              db=args.db, dsn=args.dsn, schema=args.schema, history=args.history,
                              tls=tls).check()
    except (ConfigError, CertError) as e:  # exit 78 (EX_CONFIG): systemd does not restart it
        raise ConfigFileError(str(e)) from None


def _export(store, folder: Path) -> None:
    from gateway.cloud.subscriber import export_kit_csv

    with writing("--export", folder):
        folder.mkdir(parents=True, exist_ok=True)
    ghs = store.greenhouses()
    if not ghs:
        print(f"{store.path}: no measurement stored yet: nothing to export", file=sys.stderr)
    for farm, gh in ghs:
        out = folder / f"{farm}-{gh}.csv"
        with writing("--export", out):
            n = export_kit_csv(store, farm, gh, out)
        print(f"wrote {out}: {n} minutes")


def run(args: argparse.Namespace) -> int:
    """Exit 78 (EX_CONFIG) on what the settings say wrong on their face, found before Zenoh or a
    server is asked; 2 on what may pass (PostgreSQL not answering or refusing at start, a port
    in use), which the unit restarts (docs/cloud.md, "Under systemd")."""
    import sqlite3

    from gateway.cloud.store import StoreConfigError, open_store

    if args.duration is not None and not args.duration > 0:  # also NaN
        raise CliError(f"--duration {args.duration:g}: must be a positive number of seconds")
    check_output(args.export, "--export", folder=True)  # before a run whose end it is
    s = settings(args)
    if not s.connect and not s.listen and not args.export:
        raise ConfigFileError("give --connect ENDPOINT (or --listen) to subscribe, or --export DIR")
    if s.db is None and not s.dsn:
        raise ConfigFileError("give --db FILE (SQLite) or --dsn DSN (PostgreSQL) for the cloud store")
    if not (s.connect or s.listen) and not s.dsn and not Path(s.db).exists():
        # export only: a reader must not create an empty store from a mistyped path
        raise CliError(f"{s.db}: no such cloud store (subscribe --db creates it when it "
                       f"subscribes; --export alone only reads)")
    try:
        store = open_store(s.db, s.dsn, s.schema)
    except sqlite3.Error as e:
        raise CliError(f"{s.db}: cannot open the cloud store: {e}") from None
    except (ImportError, StoreConfigError) as e:  # psycopg missing, a bad DSN, another database
        raise ConfigFileError(str(e)) from None
    except RuntimeError as e:  # CloudStoreError: the server did not answer or refused (one line,
        raise CliError(str(e)) from None  # no password): it may be starting or being provisioned
    try:
        if s.connect or s.listen:
            _subscribe(args, s, store)
        if args.export:
            _export(store, args.export)
    finally:
        store.close()
    return 0


def _subscribe(args: argparse.Namespace, s, store) -> None:
    from gateway.cloud.subscriber import Subscriber
    from gateway.sdnotify import Notifier

    notify = Notifier()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    keys = s.subscriptions()
    sub = Subscriber(store, s.connect, keys, s.mode, s.listen, extra=s.zenoh_entries(),
                     history_farms=s.farms if s.history else (), retry=s.retry)
    try:
        sub.start()
    except Exception as e:
        sub.stop()
        raise CliError(f"cannot open the Zenoh session: {e}") from None
    t0 = time.monotonic()
    last = told = t0
    waiting = ""
    try:
        while not stop.wait(0.2):
            if not notify.readied and sub.ready.is_set():
                if sub.opener.error is not None:
                    raise CliError(f"cannot subscribe: {sub.opener.error}")
                what = f"{keys[0]} (+{len(keys) - 1} more)" if len(keys) > 1 else keys[0]
                print(f"serra-subscribe ready {what} on {', '.join(s.connect + s.listen)} "
                      f"store {store.path}{' history' if sub.history else ''}", flush=True)
                notify.ready(systemd_status(sub))  # after the line: the journal shows it first
            elif not notify.readied and notify.enabled and (text := systemd_status(sub)) != waiting:
                waiting = text  # systemctl status shows it while the start waits for a router
                notify.send(f"STATUS={text}")
            if args.duration is not None and time.monotonic() - t0 >= args.duration:
                break
            if notify.readied and time.monotonic() - told >= 1:
                told = time.monotonic()
                notify.status(systemd_status(sub))
            if time.monotonic() - last >= 10:
                last = time.monotonic()
                print(f"subscribe: {_stats(sub.stats)}", file=sys.stderr, flush=True)
    finally:
        notify.stopping()  # before the last store attempt, which may take a while
        sub.stop()
        print(f"subscribe stopped: {_stats(sub.stats)}; {_stored(store)}", file=sys.stderr, flush=True)
        if sub.error is not None:
            raise CliError(str(sub.error))


def systemd_status(sub) -> str:
    """The line ``systemctl status`` shows (STATUS=): what was stored and held, Zenoh's link."""
    st = sub.stats
    held = st.received - st.stored - st.repeats - st.not_messages
    parts = [f"{_n(st.stored, 'message')} stored, {held} held"
             + (" (the store refuses them, retrying)" if held and sub.store_failing else "")]
    session = sub.session
    if session is None:
        o = sub.opener.state
        parts.append(f"zenoh connecting to {', '.join(sub.connect) or '-'} (attempt {o.attempts})")
    else:
        try:
            routers, peers = len(session.info.routers_zid()), len(session.info.peers_zid())
        except Exception:  # a session closing under us: say nothing wrong about the link
            return parts[0]
        parts.append(f"zenoh linked ({_n(routers, 'router')}, {_n(peers, 'peer')})"
                     if routers or peers else "zenoh open, not linked yet")
    return "; ".join(parts)


def _n(count: int, noun: str) -> str:
    return f"{count} {noun}{'' if count == 1 else 's'}"


def _stored(store) -> str:
    """How many messages the store holds, or why it cannot say (it may be down: exiting then
    must still say what was not stored, not end in a traceback)."""
    try:
        return f"{store.count()} messages in the store"
    except Exception as e:
        text = str(e).splitlines()[0] if str(e) else type(e).__name__
        return f"the store cannot be read ({text})"


def _stats(stats) -> str:
    """The subscriber's counters as words (``received 3, stored 3, ...``), not a dataclass repr."""
    from dataclasses import asdict

    return ", ".join(f"{k.replace('_', ' ')} {v:.1f} s" if k.endswith("_s") else
                     f"{k.replace('_', ' ')} {v}" for k, v in asdict(stats).items()).replace(
        "store s", "storing")

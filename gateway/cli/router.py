"""``python -m gateway router``: a Zenoh router with TLS, access control and upstream links."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import threading

from gateway.cli import CliError, ConfigFileError
from gateway.cli.helpformat import ExamplesHelpFormatter

DESCRIPTION = "Run a Zenoh router: TLS endpoints, mutual TLS, access control, links to upstream routers."
EPILOG = """\
The router is the Zenoh library itself in router mode. It listens on router.listen, links to
every router in router.connect (retried for ever), requires certificates signed by tls.ca when
tls.mutual is true, and applies [access] (default deny). A documented example ships as
images/gateway/router.toml; docs/fleet.md has the topology and the certificate recipe.
SIGTERM or Ctrl-C closes the session and exits 0. Zenoh's log goes to stdout (in colour on a
terminal only), Serra's own lines to stderr. RUST_LOG, when set, overrides router.log.
"""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="run a Zenoh router (TLS, access control, upstream links)",
                       description=DESCRIPTION, epilog=EPILOG,
                       formatter_class=ExamplesHelpFormatter)
    p.add_argument("--config", required=True, metavar="ROUTER.toml", help="router configuration")
    p.add_argument("--check", action="store_true",
                   help="validate the configuration, print the Zenoh config it makes, and exit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gateway.net.certs import CertError
    from gateway.net.router import serve
    from gateway.net.routerconf import load_router_config, router_entries
    from gateway.net.tomlcheck import ConfigError
    from gateway.net.zenohcfg import build

    try:
        settings = load_router_config(args.config)
        entries = router_entries(settings)
        build(entries)  # Zenoh's own checks (unknown keys in [zenoh], bad values) before start
    except (ConfigError, CertError) as exc:  # exit 78 (EX_CONFIG): systemd does not restart it
        raise ConfigFileError(str(exc)) from None
    if args.check:
        for warning in settings.warnings():
            print(f"warning: {warning}")
        print(json.dumps(entries, indent=2))
        return 0
    import os
    import sys

    import zenoh

    if not sys.stdout.isatty():  # a file, a pipe or the journal: Zenoh's log without colour codes
        os.environ.setdefault("NO_COLOR", "1")
    zenoh.init_log_from_env_or(settings.log_filter())
    logging.getLogger("serra.router").setLevel(logging.INFO)
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        return serve(settings, stop)
    except zenoh.ZError as exc:
        raise CliError(f"{args.config}: the router could not start: "
                       f"{str(exc).split(' at /')[0]}") from None

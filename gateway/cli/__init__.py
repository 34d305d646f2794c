"""Command-line dispatcher: thin layers over the library, one module per command.

Each command module defines ``add_parser(subparsers)`` (registering its arguments and
``func``) so the dispatcher knows no command by its internals.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from gateway.cli.helpformat import ArgumentParser

COMMANDS = {
    "calibrate": "gateway.cli.calibrate",
    "replay": "gateway.cli.replay",
    "diagnose": "gateway.cli.diagnose",
    "ingest": "gateway.cli.ingest",
    "export": "gateway.cli.export",
    "keys": "gateway.cli.keys",
    "run": "gateway.cli.run",
    "subscribe": "gateway.cli.subscribe",
    "certs": "gateway.cli.certs",
    "router": "gateway.cli.router",
    "vsensor": "gateway.cli.vsensor",
    "status": "gateway.cli.status",
}


QUIET_HELP = ("no progress on stderr (piped, the long commands write a 'progress:' line at each "
              "tenth of the work and at least every 30 s; notes, warnings and errors still show)")


class CliError(Exception):
    """An error to print as one clear line, exit status ``status`` (2)."""

    status = 2


class ConfigFileError(CliError):
    """A service's configuration is wrong (a file, a key, what it names): exit status 78,
    sysexits' EX_CONFIG. The systemd units list it in ``RestartPreventExitStatus=``: a wrong
    config stops the unit with its one line in the journal instead of restarting it for ever."""

    status = os.EX_CONFIG


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(  # its commands' parsers are of its class: no hyphen breaks
        prog="python -m gateway",
        description="Serra gateway tools: calibrate, replay and diagnose greenhouse climate models "
        "on kit CSV data (docs/data-format.md); ingest kit packets, manage device keys and export what "
        "was stored; run the live gateway, watch it on the status screen and subscribe to it over "
        "Zenoh; certificates and routers for a fleet.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    parser.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}",
                        help="print the installed serra version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in COMMANDS.values():
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue  # a command still being written is simply not offered
        mod.add_parser(sub)
    for command in sub.choices.values():
        _verbose_anywhere(command)
    return parser


class _CliFormatter(logging.Formatter):
    """A notice meant for the person at the command line (a record logged with
    ``extra=NOTICE`` or ``WARNING``, gateway/kitcsv.py) reads as the commands' other notes,
    ``note: …`` or ``warning: …``; any other record stays a log line naming its logger."""

    def format(self, record: logging.LogRecord) -> str:
        level = getattr(record, "notice", None)  # "note" or "warning"
        if level:
            return f"{level}: {record.getMessage()}"
        return super().format(record)


def setup_cli_logging(verbose: bool) -> None:
    """stderr logging of a command-line tool (gateway's and training's): INFO with ``-v``."""
    handler = logging.StreamHandler()
    handler.setFormatter(_CliFormatter("%(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, handlers=[handler])


def _version() -> str:
    """The installed package's version (what a bug report needs), or why there is none."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("serra")
    except PackageNotFoundError:
        return "(not installed: run from a source tree)"


def _verbose_anywhere(parser: argparse.ArgumentParser) -> None:
    """``-v`` and ``-q`` after the command too (``calibrate ... -v``, where people add it), not
    only before it; SUPPRESS leaves the value given before the command when it is not repeated
    after."""
    if "-v" not in parser._option_string_actions:
        parser.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                            help="log details to stderr")
    if "-q" not in parser._option_string_actions:
        parser.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                            help=QUIET_HELP)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _verbose_anywhere(child)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    verbose = argv[:1] in (["-v"], ["--verbose"])
    if argv[verbose:verbose + 1] == ["ingest"]:  # the service has its own parser: hand it all
        from gateway.ingest.service import main as ingest_main

        return ingest_main(argv[1 + verbose:] + ["-v"] * verbose, prog="python -m gateway ingest")
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_cli_logging(args.verbose)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except CliError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.status
    except MemoryError as exc:  # e.g. --population 10000000: say it, not numpy's traceback
        print(f"error: {args.command}: out of memory ({exc}): the options or the data ask for "
              "more than this machine has (a smaller --population, window or span)",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130

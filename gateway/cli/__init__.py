"""Command-line dispatcher: thin layers over the library, one module per command.

Each command module defines ``add_parser(subparsers)`` (registering its arguments and
``func``) so the dispatcher knows no command by its internals.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import re
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
    after_the_command_too(parser, ("-v", "-q"))
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


def after_the_command_too(parser: argparse.ArgumentParser, options: tuple[str, ...]) -> None:
    """``parser``'s flags ``options`` (``-v``, ``-q``: given before the command) taken by every
    (sub)command too: ``calibrate ... -v``, where people add it, was "unrecognized arguments".
    A command's copy defaults to SUPPRESS, so that leaving it out after the command keeps what
    was given before it (a command's own default would overwrite the namespace's)."""
    flags = [parser._option_string_actions[o] for o in options]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                for flag in flags:
                    own = child._option_string_actions.get(flag.option_strings[0])
                    if own is None:
                        child.add_argument(*flag.option_strings, dest=flag.dest,
                                           action="store_true", default=argparse.SUPPRESS,
                                           help=flag.help)
                    else:
                        own.default = argparse.SUPPRESS
                after_the_command_too(child, options)  # keys' actions


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    lead = 0  # the flags before the command, which the ingest service takes after it
    while argv[lead:lead + 1] and (argv[lead] in ("--verbose", "--quiet")
                                   or re.fullmatch(r"-[vq]+", argv[lead])):  # -v, -q, -vq
        lead += 1
    if argv[lead:lead + 1] == ["ingest"]:  # the service has its own parser: hand it all
        from gateway.ingest.service import main as ingest_main

        return ingest_main(argv[lead + 1:] + argv[:lead], prog="python -m gateway ingest")
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

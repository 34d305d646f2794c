"""``python -m training <command>``: offline tools run from the repository (not in the gateway wheel).

Each command lives in its own module exposing ``add_parser(subparsers)``, which registers the
subcommand and sets ``func``; add new commands to ``COMMANDS``.
"""

from __future__ import annotations

import argparse
import importlib

from gateway.cli import setup_cli_logging

COMMANDS = (
    "training.simulate.cli",
    "training.demo",
    "training.appliance.cli",
)


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen command; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m training",
                                     description="Serra offline tools.")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for module in COMMANDS:
        importlib.import_module(module).add_parser(sub)
    args = parser.parse_args(argv)
    setup_cli_logging(False)  # the CSV reader's notices as note: lines, as the gateway's
    if not hasattr(args, "func"):
        parser.print_help()
        return 2
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())

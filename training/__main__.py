"""``python -m training <command>``: offline tools run from the repository (not in the gateway wheel).

Each command lives in its own module exposing ``add_parser(subparsers)``, which registers the
subcommand and sets ``func``; add new commands to ``COMMANDS``.
"""

from __future__ import annotations

import importlib

from gateway.cli import setup_cli_logging
from gateway.cli.helpformat import ArgumentParser

COMMANDS = (
    "training.simulate.cli",
    "training.demo",
    "training.appliance.cli",
)


def build_parser() -> ArgumentParser:
    """The parser of every command (``--help`` pages: tests/test_training_cli_mistakes.py)."""
    parser = ArgumentParser(prog="python -m training", description="Serra offline tools.",
                            epilog="The virtual ventilation sensor's own tools (corpus, "
                            "dataset, train, tune, reference, errors, score): python -m "
                            "training.vsensor --help.")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for module in COMMANDS:
        importlib.import_module(module).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_cli_logging(False)  # the CSV reader's notices as note: lines, as the gateway's
    if not hasattr(args, "func"):
        parser.print_help()
        return 2
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())

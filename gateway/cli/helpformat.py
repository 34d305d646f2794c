"""``--help`` that never breaks a line at a hyphen.

argparse wraps with textwrap's default ``break_on_hyphens``, which split names a user types
(``almeria-`` / ``palmerillas``, ``docs/data-`` / ``format.md``) across lines. These formatters
wrap at spaces only; :class:`ArgumentParser` uses them by default and its subcommands inherit it.
"""

from __future__ import annotations

import argparse
import textwrap
from typing import Any


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, lines broken at spaces only."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return textwrap.fill(" ".join(text.split()), width, initial_indent=indent,
                             subsequent_indent=indent, break_on_hyphens=False)


class RawDescriptionHelpFormatter(HelpFormatter):
    """Options as :class:`HelpFormatter`, description and epilog as written (already wrapped)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "".join(indent + line for line in text.splitlines(keepends=True))


class ExamplesHelpFormatter(HelpFormatter):
    """Options as :class:`HelpFormatter`; in the description and epilog an indented line (an
    example command, its continuation) is kept as written and the unindented lines between them
    are prose, wrapped at spaces to the page's width."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        lines: list[str] = []
        prose: list[str] = []
        for line in [*text.splitlines(), ""]:
            if line[:1].strip():  # an unindented line: prose, wrapped with its neighbours
                prose.append(line)
                continue
            if prose:
                lines += textwrap.wrap(" ".join(" ".join(prose).split()), width,
                                       initial_indent=indent, subsequent_indent=indent,
                                       break_on_hyphens=False)
                prose = []
            lines.append(indent + line if line.strip() else "")
        return "\n".join(lines[:-1])


class ArgumentParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose ``formatter_class`` defaults to :class:`HelpFormatter`
    (``add_subparsers`` makes the subcommands' parsers of the same class)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

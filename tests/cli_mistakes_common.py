"""What the command-line mistake tests share: a few kit rows, the one error line, the prototype's options."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from gateway.kitcsv import write_kit_csv

PROTO = ["--greenhouse", "biskra-prototype", "--model", "prototype"]


def kit_csv(folder: Path, rows: int = 30, name: str = "k.csv") -> Path:
    """A few minutes of plausible kit rows (the columns of the prototype model)."""
    t = np.datetime64("2020-03-27T10:00:00", "s") + np.arange(rows) * np.timedelta64(60, "s")
    ramp = np.arange(rows, dtype=float)
    cols = {"t_in": 20 + 0.1 * ramp, "rh_in": np.full(rows, 60.0), "t_out": 15 + 0.05 * ramp,
            "rh_out": np.full(rows, 55.0), "i_glob": 400 + ramp, "wind": np.full(rows, 1.5)}
    return write_kit_csv(folder / name, t, cols)


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    line = err.splitlines()[-1]
    assert line.startswith("error: ")
    return line


def help_pages(parser: argparse.ArgumentParser) -> dict[str, str]:
    """``--help`` of ``parser`` and of each of its subcommands, by prog."""
    pages = {parser.prog: parser.format_help()}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                pages.update(help_pages(child))
    return pages


def lines_too_wide_or_broken(pages: dict[str, str]) -> list[tuple[str, str]]:
    """(prog, line) of every line wider than 80 columns or ending in a word broken at a hyphen
    (what argparse's default wrapping does to 'PCA-NARX' or 'almeria-palmerillas')."""
    lines = [(name, line) for name, text in pages.items() for line in text.splitlines()]
    return [(n, line) for n, line in lines
            if len(line) > 80 or (line.endswith("-") and line[-2:-1].isalpha())]

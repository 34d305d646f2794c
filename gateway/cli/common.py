"""Arguments and helpers shared by the data commands (calibrate, replay, diagnose)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from gateway.cli import CliError
from gateway.cli.notes import Note, echo, input_notes
from gateway.greenhouse import Greenhouse, GreenhouseError, Site, list_presets, load_greenhouse
from gateway.kitcsv import KitCsvError, parse_time
from gateway.model import MODEL_NAMES, build_model, check_parameters
from gateway.model.model import Model, check_columns
from gateway.series import DEFAULT_STEP, SAMPLINGS, Series, load_series


def add_sampling_argument(p: argparse.ArgumentParser) -> None:
    """``--sampling``: for the commands that read whole series (calibrate)."""
    p.add_argument(
        "--sampling", choices=SAMPLINGS, default="instant",
        help="what a row holds: the value at its time (instant, default) or the mean over its "
             "step (mean: the kit's minute aggregates, read through the mean hold of "
             "docs/model.md)",
    )


def add_data_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", required=True, metavar="FILE", help="kit CSV (docs/data-format.md)")
    p.add_argument(
        "--greenhouse",
        required=True,
        metavar="PRESET|FILE.toml",
        help=f"greenhouse description: a preset ({', '.join(list_presets())}) or a TOML file",
    )
    p.add_argument("--model", required=True, choices=MODEL_NAMES, metavar="MODEL",
                   help=f"climate model: {', '.join(MODEL_NAMES)} (README.md, 'Models')")
    p.add_argument("--step", type=positive_number, metavar="S",
                   help=f"model step [s] (default {DEFAULT_STEP:g}, or the rows' own spacing when "
                   "they are more than 5 minutes apart: 10- and 15-minute loggers)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_site_argument(p)


def add_site_argument(p: argparse.ArgumentParser) -> None:
    """``--site LAT,LON``: for the commands that run a model over a kit CSV."""
    p.add_argument(
        "--site",
        type=_site,
        metavar="LAT,LON",
        help="where the data was recorded [deg N, deg E], overriding the greenhouse's [site]: the "
        "sun's position there sets the clear sky that the cloudiness, and so the sky "
        "temperature, is read against (docs/effects.md, 'Sky temperature')",
    )


def with_site(gh: Greenhouse, site: tuple[float, float] | None) -> Greenhouse:
    """The greenhouse with ``--site LAT,LON`` applied (unchanged without one)."""
    return gh if site is None else replace(gh, site=Site(*site))


def positive_number(text: str) -> float:
    """argparse type: a finite number > 0 (a zero or negative step or length would be a
    traceback later)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _site(text: str) -> tuple[float, float]:
    """argparse type: ``LAT,LON`` in degrees (north and east positive)."""
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LAT,LON in degrees, got {text!r}") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise argparse.ArgumentTypeError(f"latitude must be in [-90, 90] and longitude in "
                                         f"[-180, 180] degrees, got {text!r}")
    return lat, lon


def _whole_number(text: str, least: int, said: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"must be {said}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1 (0 iterations would "calibrate" to the start point)."""
    return _whole_number(text, 1, "at least 1")


def non_negative_int(text: str) -> int:
    """argparse type: a count that may be none (0 closed-loop rounds: the series-parallel fit
    alone); a negative one would silently mean 0."""
    return _whole_number(text, 0, "0 or more")


seed_int = non_negative_int
"""argparse type of a seed: numpy's generators refuse a negative one, which would be a traceback
after the data was read."""


def add_seed_argument(p: argparse.ArgumentParser, what: str) -> None:
    """``--seed N``: the one wording for every command that draws random numbers."""
    p.add_argument("--seed", type=seed_int, default=0, metavar="N",
                   help=f"random seed of {what}, 0 or more (default 0)")


@dataclass(frozen=True)
class Inputs:
    """What a data command runs on: the resampled data, the greenhouse, the model, and the
    notes the data gives rise to (gateway/cli/notes.py), already printed on stderr."""

    series: Series
    gh: Greenhouse
    model: Model
    notes: list[Note]


def load_inputs(args: argparse.Namespace) -> tuple[Series, Greenhouse, Model]:
    """Greenhouse, model and resampled data, with errors turned into one clear line (the
    notes on stderr only; the commands use :func:`load_run`)."""
    run = load_run(args)
    return run.series, run.gh, run.model


def load_run(args: argparse.Namespace) -> Inputs:
    """Greenhouse, model and resampled data, with errors turned into one clear line, and the
    notes on the data (printed on stderr now, before any long computation)."""
    try:
        gh = with_site(load_greenhouse(args.greenhouse), getattr(args, "site", None))
        model = build_model(args.model, gh)
        check_parameters(model, gh)
    except GreenhouseError as exc:
        raise CliError(str(exc)) from None
    try:
        series = load_series(args.data, step=args.step, required=model.requires,
                             sampling=getattr(args, "sampling", "instant"))
    except KitCsvError as exc:
        raise CliError(str(exc)) from None
    if len(series) < 2:
        raise CliError(
            f"{args.data}: {len(series)} sample(s) on the {series.step:g} s grid; every tool needs "
            f"at least two (one step to predict)"
        )
    empty = [c for c in model.requires if c in series.columns and c not in series]
    if empty:
        raise CliError(
            f"{args.data}: column(s) {', '.join(empty)} hold no value on the {series.step:g} s grid "
            f"(every cell empty or in gaps), and the '{model.name}' model needs them"
        )
    try:
        check_columns(model, [c for c in series.columns if c in series], args.data)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    notes = _step_note(series, args) + input_notes(series, gh, model, args.data, args.greenhouse,
                                                   getattr(args, "command", None))
    echo(notes)
    return Inputs(series, gh, model, notes)


def _step_note(series: Series, args: argparse.Namespace) -> list[Note]:
    """Say so when the model step was taken from the rows rather than the default."""
    if args.step is not None or series.step == DEFAULT_STEP:
        return []
    return [Note("step_from_rows", f"{args.data}: rows are {series.native_step:g} s apart "
                 f"(median), so the model runs at a {series.step:g} s step (--step S for another)")]


def parse_span(text: str | None, series: Series) -> tuple[int, int] | None:
    """``START/END`` (ISO 8601 times or dates; UTC when no offset) → row indices [a, b)."""
    if not text:
        return None
    parts = text.split("/")
    if len(parts) != 2:
        raise CliError(f"--calibrate-on {text!r}: expected START/END, two ISO 8601 dates or times "
                       f"(UTC unless an offset is given), e.g. 2009-10-21/2009-10-23")
    stamps = []
    for name, part in zip(("START", "END"), parts, strict=True):
        try:
            stamps.append(parse_when(part))
        except ValueError as exc:  # the parser's own words only when they say more
            why = "" if str(exc).startswith("Invalid isoformat") else f" ({exc})"
            raise CliError(f"--calibrate-on {text!r}: {name} {part!r} is not an ISO 8601 date or "
                           f"time{why}, e.g. 2009-10-21 or 2009-10-21T06:00") from None
    if stamps[1] <= stamps[0]:
        raise CliError(f"--calibrate-on {text!r}: END is not after START")
    a, b = series.index_of(stamps[0]), series.index_of(stamps[1])
    if b - a < 2:
        raise CliError(
            f"--calibrate-on {text!r} covers {max(b - a, 0)} samples of {series.source} "
            f"({series.time[0]}Z to {series.time[-1]}Z)"
        )
    return a, b


def parse_when(text: str) -> np.datetime64:
    """A time given on the command line (``--calibrate-on``, ``export --from/--to``): ISO 8601
    date or date and time, UTC unless an offset is given (``2026-03-01``, ``2026-03-01T06:00``,
    ``2026-03-01T06:00+01:00``). The kit CSV itself wants the offset written (kitcsv.parse_time)."""
    text = text.strip()
    if "T" not in text and len(text) == 10:
        text += "T00:00:00"
    if not (text.endswith("Z") or "+" in text[10:] or "-" in text[10:]):
        text += "Z"
    return parse_time(text)


def read_params_file(path: str, model: Model, gh: Greenhouse) -> np.ndarray:
    """Parameters written by ``calibrate --out`` (TOML ``[params]``), checked against the model;
    keys the file lacks take the greenhouse's defaults."""
    from gateway.model.params_file import ParamsFileError, read_params

    try:
        return read_params(path, model, gh)
    except ParamsFileError as exc:
        raise CliError(str(exc)) from None


def no_stdout(path: str | Path, option: str, kind: str = "file") -> None:
    """Refuse ``-`` for an output that cannot go to stdout (a ``kind`` of files, a binary, or
    beside the report stdout carries): it made a file named ``-``. ``export --out -`` is the
    one output written on stdout."""
    if str(path) == "-":
        raise CliError(f"{option} -: this output is not written to stdout (stdout carries the "
                       f"command's report); give a {kind} name")


def check_output(path: str | Path | None, option: str, folder: bool = False,
                 inputs: dict[str, str | Path | None] | None = None) -> None:
    """Refuse an output the command could not write, before any computation (so that an hour
    of calibration is not lost to a typo in ``--out``): a file's folder must exist and be
    writable and the file must not be a folder; a ``folder`` output (created with its parents)
    must not be a file and its nearest existing parent must be a writable folder. An output
    that is one of the command's ``inputs`` (option → path) is refused: writing it would
    replace the data it was computed from."""
    if not path:
        return
    no_stdout(path, option, "folder" if folder else "file")
    p = Path(path)
    for name, source in (inputs or {}).items():
        if source and Path(source).is_file() and p.exists() and p.samefile(source):
            raise CliError(f"{option} {path}: is the {name} input; writing it would replace "
                           f"what it was computed from (give another file name)")
    if folder:
        if p.exists() and not p.is_dir():
            raise CliError(f"{option} {path}: exists and is not a folder")
        parent = p
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    else:
        if p.is_dir():
            raise CliError(f"{option} {path}: is a folder; give a file name")
        parent = p.parent
        if not parent.exists():
            raise CliError(f"{option} {path}: folder {parent} does not exist")
    if not parent.is_dir():
        raise CliError(f"{option} {path}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CliError(f"{option} {path}: folder {parent} is not writable by this user")


def check_figure(path: str | None, option: str) -> None:
    """Refuse a figure name matplotlib cannot write (``replay.txt``) before the run it would
    draw: the error would otherwise come after all the work. No ending: matplotlib writes PNG."""
    if not path:
        return
    from gateway.plots import figure_formats

    ending = Path(path).suffix.lower().removeprefix(".")
    formats = figure_formats()
    if ending and ending not in formats:
        raise CliError(f"{option} {path}: cannot draw a '.{ending}' file; give a figure name "
                       f"ending in .png, .svg or .pdf (all: {', '.join(formats)})")


@contextmanager
def writing(option: str, path: str | Path) -> Iterator[None]:
    """Turn an OSError while writing an output (disk full, permissions changed since
    :func:`check_output`) into one line naming the option and the path."""
    try:
        yield
    except OSError as exc:
        raise CliError(f"{option} {path}: cannot write: {exc.strerror or exc}") from None


def write_params_file(path: str, model: Model, params: dict[str, float], header: str) -> None:
    lines = [f"# {header}", f'model = "{model.name}"', "", "[params]"]
    for p in model.parameters:
        lines.append(f"{p.name} = {params[p.name]!r}  # [{p.unit}] {p.description}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def dump_json(obj: Any) -> None:
    """One JSON object on stdout; NaN becomes null."""
    json.dump(_clean(obj), sys.stdout, indent=2)
    sys.stdout.write("\n")


def _clean(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj

"""``python -m training simulate``: write a simulated kit CSV and its truth files."""

from __future__ import annotations

import argparse
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

from gateway.cli.common import positive_number, seed_int
from gateway.cli.helpformat import RawDescriptionHelpFormatter
from training.simulate.effects import EffectSpecError, describe_effects, parse_effect
from training.simulate.plant import PRESETS
from training.simulate.weather import CLIMATES, DEFAULT_START, WEATHER_SOURCES, parse_start

HELP_WIDTH = 79
"""The epilog is written as is (raw): wrapped here for an 80-column terminal."""


def _wrapped(text: str, indent: str = "") -> str:
    return "\n".join(textwrap.fill(line, HELP_WIDTH, subsequent_indent=indent,
                                   break_on_hyphens=False) for line in text.splitlines())


EPILOG = f"""\
effects (--effect, repeatable; never declared in the CSV, listed in the truth
JSON):
  spec: name[@YYYY-MM-DD[THH:MM[:SS]]][:key=value[,key=value...]]  (times UTC)
{_wrapped(describe_effects(), " " * 4)}

examples:
  python -m training simulate --plant almeria --weather bleiswijk --days 14 \\
      --start 2009-11-01 \\
      --effect cover_transmission@2009-11-08T10:00:factor=0.7 \\
      --seed 1 --out data.csv
  python -m training simulate --plant prototype --weather biskra --days 5 \\
      --effect heater@2019-01-28:power=30,night_only=1 --out proto.csv

{_wrapped("outputs: the kit CSV (docs/data-format.md), <stem>.truth.json (plant, weather, "
          "seed, effects, sensor errors, units) and <stem>.truth.npz (true states, flows "
          "[m3 s-1], fluxes [W m-2]). Default start: "
          + ", ".join(f"{k} {v}" for k, v in DEFAULT_START.items()) + ". See docs/simulator.md.")}
"""


def _step_seconds(text: str) -> float:
    """argparse type of ``--step``: whole seconds, 1 or more. The kit CSV's times are whole
    seconds: 0.5 s rounded the grid to a zero step (a ZeroDivisionError), 1.5 s to an uneven one."""
    value = positive_number(text)
    if value != round(value):
        raise argparse.ArgumentTypeError(f"must be whole seconds (the CSV's times are), got {text!r}")
    return value


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``simulate`` subcommand."""
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a greenhouse on real or synthetic weather -> kit CSV + truth",
        description=_wrapped("Reference greenhouse simulator: air, cover and soil nodes, crop "
                             "transpiration, Kittas ventilation with a vent controller, sensor "
                             "models, and injectable effects."),
        epilog=EPILOG,
        formatter_class=RawDescriptionHelpFormatter,
    )
    parser.add_argument("--plant", choices=sorted(PRESETS), default="almeria",
                        help="greenhouse simulated (default almeria); the gateway tools read its "
                        "CSV with --greenhouse almeria-palmerillas --model almeria, or "
                        "biskra-prototype --model prototype for the prototype")
    parser.add_argument("--weather", choices=WEATHER_SOURCES, default="bleiswijk", metavar="NAME",
                        help="bleiswijk = measured 2009-10-20..2009-12-10; "
                        f"{', '.join(CLIMATES)} = synthetic seeded days (default bleiswijk)")
    parser.add_argument("--start", default=None, metavar="YYYY-MM-DD[THH:MM]",
                        help="first sample, UTC (default per weather, below)")
    parser.add_argument("--days", type=positive_number, default=14.0, metavar="D",
                        help="length [d] (default 14)")
    parser.add_argument("--step", type=_step_seconds, default=60.0, metavar="S",
                        help="output step [s], whole seconds (default 60)")
    parser.add_argument("--effect", action="append", default=[], metavar="SPEC",
                        help="inject an effect (repeatable), see below")
    parser.add_argument("--seed", type=seed_int, default=0, metavar="N",
                        help="seed of synthetic weather and sensor errors, 0 or more (default 0)")
    parser.add_argument("--out", required=True, metavar="FILE.csv",
                        help="path of the kit CSV to write (its folder is created)")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the ``simulate`` subcommand."""
    from training.simulate.run import simulate

    if args.out == "-":  # three files (CSV, truth JSON and npz) named after it, not one text
        print("error: --out -: the simulator writes the kit CSV and its truth files beside it, not "
              "to stdout; give the kit CSV's file name", file=sys.stderr)
        return 2
    if Path(args.out).is_dir():
        print(f"error: --out {args.out}: is a folder; give the kit CSV's file name", file=sys.stderr)
        return 2

    try:
        start = parse_start(args.start or DEFAULT_START[args.weather])
        parsed = [(s, parse_effect(s, start)) for s in args.effect]
        effects = [e for _, e in parsed if e is not None]
    except (EffectSpecError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    end = start + np.timedelta64(int(round(args.days * 86400.0)), "s")
    for spec, effect in parsed:
        if effect is not None and effect.start >= end:  # a wrong year or month: the effect would never act
            print(f"note: --effect {spec}: starts at {effect.start}Z, after the simulated span "
                  f"({start}Z to {end}Z): it has no influence on the data", file=sys.stderr)
    began = time.perf_counter()
    try:
        result = simulate(args.plant, args.weather, start, args.days, effects, args.seed,
                          args.step)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        paths = result.write(args.out)
    except OSError as exc:
        print(f"error: --out {args.out}: cannot write: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"simulated {args.days:g} d of {args.plant} on {args.weather} weather in "
          f"{time.perf_counter() - began:.1f} s ({len(result.time)} rows, "
          f"{len(effects)} effect(s))")
    for path in paths:
        print(f"  wrote {path}")
    return 0

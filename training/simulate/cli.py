"""``python -m training simulate``: write a simulated kit CSV and its truth files."""

from __future__ import annotations

import argparse
import sys
import time

from training.simulate.effects import EffectSpecError, describe_effects, parse_effect
from training.simulate.plant import PRESETS
from training.simulate.weather import DEFAULT_START, WEATHER_SOURCES, parse_start

EPILOG = f"""\
effects (--effect, repeatable; never declared in the CSV, listed in the truth JSON):
  spec: name[@YYYY-MM-DD[THH:MM[:SS]]][:key=value[,key=value...]]   (times UTC)
{describe_effects()}

examples:
  python -m training simulate --plant almeria --weather bleiswijk --days 14 \\
      --start 2009-11-01 --effect cover_transmission@2009-11-08T10:00:factor=0.7 \\
      --seed 1 --out data.csv
  python -m training simulate --plant prototype --weather biskra --days 5 \\
      --effect heater@2019-01-28:power=30,night_only=1 --out proto.csv

outputs: the kit CSV (docs/data-format.md), <stem>.truth.json (plant, weather, seed, effects,
sensor errors, units) and <stem>.truth.npz (true states, flows [m3 s-1], fluxes [W m-2]).
Default start: {", ".join(f"{k} {v}" for k, v in DEFAULT_START.items())}.
See docs/simulator.md.
"""


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register the ``simulate`` subcommand."""
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a greenhouse on real or synthetic weather -> kit CSV + truth",
        description="Reference greenhouse simulator: air, cover and soil nodes, crop "
        "transpiration, Kittas ventilation with a vent controller, sensor models, and "
        "injectable effects.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--plant", choices=sorted(PRESETS), default="almeria",
                        help="greenhouse preset (default: almeria)")
    parser.add_argument("--weather", choices=WEATHER_SOURCES, default="bleiswijk",
                        help="bleiswijk = measured 2009-10-20..2009-12-10; biskra, almeria = "
                        "synthetic seeded days (default: bleiswijk)")
    parser.add_argument("--start", default=None,
                        help="first sample, UTC, YYYY-MM-DD[THH:MM] (default per weather)")
    parser.add_argument("--days", type=float, default=14.0, help="length [d] (default: 14)")
    parser.add_argument("--step", type=float, default=60.0, help="output step [s] (default: 60)")
    parser.add_argument("--effect", action="append", default=[], metavar="SPEC",
                        help="inject an effect (repeatable), see below")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of synthetic weather and sensor errors (default: 0)")
    parser.add_argument("--out", required=True, help="path of the kit CSV to write")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the ``simulate`` subcommand."""
    from training.simulate.run import simulate

    try:
        start = parse_start(args.start or DEFAULT_START[args.weather])
        effects = [e for e in (parse_effect(s, start) for s in args.effect) if e is not None]
    except (EffectSpecError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    began = time.perf_counter()
    try:
        result = simulate(args.plant, args.weather, start, args.days, effects, args.seed,
                          args.step)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    paths = result.write(args.out)
    print(f"simulated {args.days:g} d of {args.plant} on {args.weather} weather in "
          f"{time.perf_counter() - began:.1f} s ({len(result.time)} rows, "
          f"{len(effects)} effect(s))")
    for path in paths:
        print(f"  wrote {path}")
    return 0

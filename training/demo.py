"""``python -m training demo`` (``make demo``): the offline loop on shipped data.

1. The reference simulator (training/simulate) grows 10 days (``--days``) of an Almería-type
   greenhouse on the shipped Bleiswijk weather from 2009-10-26, with an effect nobody declares:
   a 25 W m-2 heater switched on at 41/72 of the length after the start (day 5.69 of 10,
   2009-10-31T16:40Z). Ten days because the diagnosis judges a change on the held-out days after
   it (at least 3, power from 4-5) and holds out the second half; a heater because a cover
   whitening, the demo's change until 2026-11-27, is regulated away by the house's measured vent
   controller (README, "make demo").
2. ``calibrate`` fits the almeria model on the first 2 days (RSBA, thesis settings).
3. ``replay`` runs the online estimator over the whole run as the live gateway would, beside the
   constant-parameter model and persistence, and plots it.
4. ``diagnose`` looks for what the model lacks and reports it with the error before and after.

Everything lands in ``--out`` (default ``out/demo``): the CSV and its truth, params.toml,
replay.png, predictions.csv, and the diagnosis report. It lives in training/ because it needs
the simulator, which the gateway wheel does not carry; steps 2–4 are the gateway's own commands.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from gateway.cli.common import seed_int

START = "2009-10-26"  # simulator start, 00:00 UTC
DAYS = 10.0  # the live [diagnosis] default: 5 held-out days, 4.3 of them after the change
CHANGE_AT = 41 / 72  # the change's start as a fraction of the length (16:40 on day 6 of 10)
POWER = 25.0  # [W m-2 floor] the undeclared heater (the generality suite's size)


def effect_start(days: float) -> np.datetime64:
    """When the heater starts in a ``days``-long run: ``CHANGE_AT`` × ``days`` after
    ``START`` (UTC), rounded to the minute (10 d → 2009-10-31T16:40)."""
    return np.datetime64(START, "m") + np.timedelta64(round(CHANGE_AT * days * 1440.0), "m")


def effect_spec(days: float) -> str:
    """The undeclared effect's simulator spec for a ``days``-long run
    (10 d → ``heater@2009-10-31T16:40:power=25``)."""
    return f"heater@{_when(days)}:power={POWER:g}"


def _when(days: float) -> str:
    return np.datetime_as_string(effect_start(days), unit="m")


MIN_DAYS = 3.0
"""[d] the first 2 days calibrate; the rest validates and is replayed and diagnosed."""


def _days(text: str) -> float:
    """argparse type of ``--days``: a number of at least ``MIN_DAYS``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value >= MIN_DAYS:  # also refuses NaN
        raise argparse.ArgumentTypeError(f"must be at least {MIN_DAYS:g} (the first 2 days "
                                         f"calibrate), got {text!r}")
    return value


def output_folder(text: str) -> str:
    """argparse type of an output folder (``--out``): a folder, or a path where one can be made
    (also ``training.demo_heater``'s)."""
    if text == "-":  # made a folder named '-'
        raise argparse.ArgumentTypeError("- is not written to stdout (a folder of outputs); give a "
                                         "folder name")
    p = Path(text)
    for parent in (p, *p.parents):
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{parent} exists and is not a folder")
            break
    return text


def _setting(text: str) -> str:
    """argparse type of ``--set``: what ``replay --set`` takes, checked before step 1 runs."""
    from gateway.cli import CliError
    from gateway.cli.replay import _overrides

    try:
        _overrides([text])
    except CliError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="end-to-end offline run on shipped data: simulate → calibrate → replay → diagnose",
        description=__doc__.split("\n\n")[0].replace("``", "")
        + f" Steps: simulate {DAYS:g} days (--days) from {START} with an undeclared"
        f" {POWER:g} W m-2 heater from {CHANGE_AT:.3f} × the length on"
        f" ({_when(DAYS)}Z for {DAYS:g} days), calibrate on the first 2 days, replay, diagnose.",
    )
    p.add_argument("--out", type=output_folder, default="out/demo", metavar="DIR",
                   help="output folder, created with its parents (default out/demo)")
    p.add_argument("--days", type=_days, default=DAYS, metavar="D",
                   help=f"days to simulate from {START} (default {DAYS:g}); the undeclared heater "
                   f"({POWER:g} W m-2) starts {CHANGE_AT:.3f} × D after the start "
                   f"({_when(DAYS)}Z for {DAYS:g})")
    p.add_argument("--seed", type=seed_int, default=1, metavar="N",
                   help="simulator and swarm seed, 0 or more (default 1)")
    p.add_argument("--set", action="append", default=[], type=_setting, metavar="OUTPUT.KEY=VALUE",
                   help="an online setting of step 3, passed to replay's --set (e.g. "
                   "t_in.iterations=10 for a quicker, rougher replay); repeatable")
    p.set_defaults(func=run)


def _step(title: str) -> float:
    print(f"\n== {title}", flush=True)
    return time.perf_counter()


def _took(t0: float) -> None:
    print(f"(step took {time.perf_counter() - t0:.1f} s)", flush=True)


def run(args: argparse.Namespace) -> int:
    from gateway.cli import main as gateway_main
    from training.simulate import simulate
    from training.simulate.weather import BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = out / "almeria.csv"
    t_all = t0 = _step(f"1/4 simulate {args.days:g} days of an Almería-type greenhouse on "
                       "Bleiswijk weather")
    effect = effect_spec(args.days)
    result = simulate("almeria", "bleiswijk", start=START, days=args.days,
                      effects=[effect], seed=args.seed)
    result.write(data)
    print(f"wrote {data} (+ truth) in {time.perf_counter() - t0:.1f} s; undeclared effect: {effect}")
    # the weather is Bleiswijk's: the sun (and with it the cloudiness the sky temperature is read
    # from) is computed there, not at the preset's Almería site
    common = ["--data", str(data), "--greenhouse", "almeria-palmerillas", "--model", "almeria",
              "--site", f"{BLEISWIJK_LATITUDE},{BLEISWIJK_LONGITUDE}"]
    params = out / "params.toml"
    t0 = _step("2/4 calibrate the almeria model on the first 2 days (RSBA), validate on the rest")
    code = gateway_main(["calibrate", *common, "--algorithm", "rsba", "--seed", str(args.seed),
                         "--calibrate-on", "2009-10-26/2009-10-28", "--out", str(params)])
    if code:
        return code
    _took(t0)
    t0 = _step("3/4 replay: the online estimator sample by sample, vs constant parameters and "
               "persistence")
    code = gateway_main(["replay", *common, "--params", str(params), "--seed", str(args.seed),
                         *(a for item in args.set for a in ("--set", item)),
                         "--out", str(out / "predictions.csv"), "--plot", str(out / "replay.png")])
    if code:
        return code
    _took(t0)
    t0 = _step("4/4 diagnose: residual → effect → error before and after, on held-out data")
    code = gateway_main(["diagnose", *common, "--seed", str(args.seed), "--report",
                         str(out / "diagnosis")])
    if code:
        return code
    _took(t0)
    print(f"\nall outputs in {out}/ (replay.png, diagnosis/report.md) after "
          f"{time.perf_counter() - t_all:.0f} s; the undeclared effect was {effect}",
          file=sys.stderr)
    return 0

"""The identifiability dataset of thesis §III.4.2.1.2 (table 4), rebuilt on real weather.

Two days (2880 one-minute rows) of the shipped Bleiswijk weather, scaled towards a Biskra
winter (radiation × 1.4, temperature + 3 °C), drive the prototype equations with the assumed
parameters of table 4. Since issue 10 the inside temperature comes from the independent fine
RK4 reference (training/step_reference.py: drivers varying continuously within the minute) and
every column holds the kit's per-minute mean, so a calibrator that recovers the parameters
also shows that the model's integration is right; before, the data were made by the model's own
step and could only show that the search converges. ``python -m training.identifiability``
rebuilds ``training/data/identifiability_prototype_2days.csv``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from gateway.kitcsv import write_kit_csv
from gateway.model import psychrometrics as psy
from gateway.series import Series, load_series
from training import step_reference as ref

ASSUMED = ref.ASSUMED
"""Assumed parameter values of table 4."""
DATASET = Path(__file__).parent / "data" / "identifiability_prototype_2days.csv"
STEP_S = 60.0
H_S = 1.0
"""RK4 step of the reference [s]."""


def build(days: float = 2.0, step: float = STEP_S, sampling: str = "mean", h: float = H_S) -> Series:
    """Per-minute kit rows of the reference run with the assumed parameters."""
    weather = ref.biskra_weather(days)
    trajectory = ref.integrate(weather, ASSUMED, h=h)
    cols = ref.kit_rows(weather, trajectory, h, step, sampling)
    # Inside air holds the outside vapour: RH follows from the inside temperature.
    p_w = psy.vapour_pressure(cols["t_out"], cols["rh_out"])
    cols["rh_in"] = np.clip(psy.relative_humidity(cols["t_in"], p_w), 0.0, 100.0)
    order = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind")
    n = len(cols["t_in"])
    return Series(ref.time_axis(n, step), step, {k: cols[k] for k in order},
                  source="identifiability", sampling=sampling)


def load(path: Path = DATASET) -> Series:
    """The shipped dataset: per-minute means (``Series.sampling = "mean"``)."""
    return load_series(str(path), sampling="mean")


def write(path: Path = DATASET) -> Path:
    s = build()
    return write_kit_csv(path, s.time, s.columns, digits=12)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.identifiability",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=DATASET, metavar="FILE.csv",
                    help="where to write the dataset (default: the shipped "
                         "training/data/identifiability_prototype_2days.csv)")
    args = ap.parse_args(argv)
    if str(args.out) == "-":  # made a file named '-'
        ap.error("--out -: the dataset is not written to stdout; give its file name")
    if args.out.is_dir():  # was IsADirectoryError's traceback, after the dataset was built
        ap.error(f"--out {args.out}: is a folder; give the dataset's file name")
    print(write(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

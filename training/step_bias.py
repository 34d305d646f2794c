"""The exact step's own bias (issue 10): identify the prototype parameters from the RK4 reference.

``python -m training.step_bias`` prints the tables of docs/model.md ("The step's own bias"):

1. *What causes it*: the step before issue 10 (zero-order hold, coefficients frozen at the start,
   ``step.FROZEN``) identified on reference data in which the physics is frozen over each minute
   the same way, then unfrozen one part at a time: the drivers, the inside coefficient h_i, the
   air density (had rho_a followed T_in), instantaneous vs per-minute mean rows.
2. *Before and after*: every integration scheme on the reference at 1 and 5 minutes, for
   instantaneous rows and for per-minute means (with and without the mean hold of the drivers).

Each figure is the largest relative error of the four parameters (and each one's) at the
minimum of the calibration cost, found by Gauss–Newton from the assumed values: the bias of the
scheme itself, with no search noise (a swarm converges to the same minimum).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from gateway.cli.common import positive_number
from gateway.estimate.objective import Objective
from gateway.greenhouse import Greenhouse, load_greenhouse
from gateway.model import build_model
from gateway.model.drivers import prepare_drivers
from gateway.model.model import Model
from gateway.model.step import FROZEN, Integration
from gateway.series import Series
from training import step_reference as ref

SCHEMES = {
    "zero-order hold, frozen (before)": FROZEN,
    "zero-order hold, re-linearised": Integration("zero_order", True),
    "first-order hold, frozen": Integration("first_order", False),
    "first-order hold, re-linearised (after)": Integration(),
}


@dataclass
class Identified:
    """Relative errors [%] of the identified parameters, by name, and the worst one."""

    errors: dict[str, float]

    @property
    def worst(self) -> float:
        return max(abs(v) for v in self.errors.values())


def identify(model: Model, series: Series, gh: Greenhouse, mode: str = "one_step",
             iterations: int = 12) -> Identified:
    """Gauss–Newton on the calibration residuals (one-step or free-run) from the assumed
    values; returns the relative errors of the minimum."""
    x = prepare_drivers(series, gh)
    truth = np.array([ref.ASSUMED[n] for n in model.names])
    obj = Objective(model, x, gh, series.step, np.arange(len(truth)), truth,
                    [(0, len(series))], mode=mode)
    theta = truth.copy()
    k = len(theta)
    for _ in range(iterations):
        h = 1e-6 * theta
        rows = np.vstack([theta, theta + np.diag(h)])
        r = obj.residuals(rows)[0][:, 1:]
        ok = np.isfinite(r).all(axis=0)
        jac = (r[1:, ok] - r[0, ok]) / h[:, None]
        d = np.linalg.lstsq(jac.T, -r[0, ok], rcond=None)[0]
        theta = theta + d
        if np.max(np.abs(d / theta)) < 1e-10:
            break
    return Identified({n: 100.0 * (theta[j] / truth[j] - 1.0) for j, n in enumerate(model.names[:k])})


def rows(weather: ref.Weather, trajectory: np.ndarray, h: float, step: float, sampling: str
         ) -> Series:
    cols = ref.kit_rows(weather, trajectory, h, step, sampling)
    return Series(ref.time_axis(len(cols["t_in"]), step), step, cols, source="reference",
                  sampling=sampling)


def causes(weather: ref.Weather, h: float, model: Model, gh: Greenhouse
           ) -> list[tuple[str, Identified, Identified]]:
    """Table 1: the step before issue 10 on reference data with parts of the physics frozen."""
    frozen = replace(model, integration=FROZEN)
    cases = [
        ("drivers, h_i frozen over each minute (what the step assumes)",
         dict(freeze_drivers=True, freeze_hi=True), "instant"),
        ("h_i continuous, drivers frozen", dict(freeze_drivers=True), "instant"),
        ("drivers continuous, h_i frozen", dict(freeze_hi=True), "instant"),
        ("drivers and h_i continuous", {}, "instant"),
        ("drivers and h_i continuous, per-minute means", {}, "mean"),
        ("+ rho_a(T_in) continuous (moist air, III.2)", dict(rho="moist"), "mean"),
        ("+ rho_a(T_in) frozen over each minute", dict(rho="moist_frozen"), "mean"),
    ]
    out = []
    for label, kw, sampling in cases:
        traj = ref.integrate(weather, ref.ASSUMED, h=h, sampling=sampling, **kw)
        s = rows(weather, traj, h, 60.0, sampling)
        s = replace(s, sampling="instant")  # the step before issue 10 had no mean hold
        out.append((label, identify(frozen, s, gh, "one_step"), identify(frozen, s, gh, "free_run")))
    return out


def before_after(weather: ref.Weather, h: float, model: Model, gh: Greenhouse,
                 steps: Iterable[float] = (60.0, 300.0)) -> list[tuple[str, str, Identified, Identified]]:
    """Table 2: every scheme × step × data sampling (means read with and without the hold)."""
    out = []
    for step in steps:
        # the cloudiness is read from the rows themselves, as the model reads it (step_reference)
        traj = {s: ref.integrate(weather, ref.ASSUMED, h=h, sampling=s, row_step=step)
                for s in ("instant", "mean")}
        data = {
            "instant": rows(weather, traj["instant"], h, step, "instant"),
            "mean, read as instant": replace(rows(weather, traj["mean"], h, step, "mean"),
                                             sampling="instant"),
            "mean, mean hold": rows(weather, traj["mean"], h, step, "mean"),
        }
        for label, scheme in SCHEMES.items():
            m = replace(model, integration=scheme)
            for kind, s in data.items():
                out.append((f"{step / 60:g} min", f"{label}; {kind}", identify(m, s, gh, "one_step"),
                            identify(m, s, gh, "free_run")))
    return out


def diagnosis_grid(weather: ref.Weather, h: float, model: Model, gh: Greenhouse
                   ) -> list[tuple[str, Identified, Identified]]:
    """Table 3: the diagnosis's 5-minute grid (``diagnose.fit.coarsen`` of per-minute means:
    every 5th reading of T_in, block means of the inputs over the 5 minutes that follow) with
    the zero-order hold the diagnosis keeps, against 5-minute means with the default step."""
    from gateway.diagnose.fit import coarsen

    traj = ref.integrate(weather, ref.ASSUMED, h=h)
    minutes = rows(weather, traj, h, 60.0, "mean")
    grid = coarsen(replace(minutes, sampling="instant"), 5)
    # the cloudiness read from the 5-minute rows, as the model reads it (step_reference)
    means = rows(weather, ref.integrate(weather, ref.ASSUMED, h=h, row_step=300.0), h, 300.0, "mean")
    cases = [
        ("diagnosis grid, zero-order hold, frozen (the diagnosis today)", FROZEN, grid),
        ("diagnosis grid, zero-order hold, re-linearised", Integration("zero_order", True), grid),
        ("5-minute means, mean hold, first-order hold re-linearised", Integration(), means),
    ]
    return [(label, identify(replace(model, integration=sc), s, gh, "one_step"),
             identify(replace(model, integration=sc), s, gh, "free_run")) for label, sc, s in cases]


def _fmt(r: Identified, names: list[str]) -> str:
    return " / ".join(f"{r.errors[n]:+.3f}" for n in names)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.step_bias", description=__doc__.split("\n")[0])
    ap.add_argument("--h", type=positive_number, default=1.0, metavar="S",
                    help="RK4 step of the reference [s] (default 1)")
    ap.add_argument("--skip-causes", action="store_true", help="only the before/after table")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    gh = load_greenhouse("biskra-prototype")
    model = build_model("prototype", gh)
    names = model.names
    weather = ref.biskra_weather(2.0)
    head = (f"| {{}} | one-step: worst [%] | one-step: {' / '.join(n for n in names)} [%] "
            f"| free run: worst [%] | free run: each [%] |")
    if not args.skip_causes:
        print("What causes the bias: the step before issue 10 on partly frozen reference data (1 min)\n")
        print(head.format("reference data"))
        print("| --- | --- | --- | --- | --- |")
        for label, one, free in causes(weather, args.h, model, gh):
            print(f"| {label} | {one.worst:.3f} | {_fmt(one, names)} | {free.worst:.3f} | "
                  f"{_fmt(free, names)} |", flush=True)
        print()
    print("Before and after: every scheme on the continuous reference\n")
    print(head.format("step: scheme; data"))
    print("| --- | --- | --- | --- | --- |")
    for step, label, one, free in before_after(weather, args.h, model, gh):
        print(f"| {step}: {label} | {one.worst:.3f} | {_fmt(one, names)} | {free.worst:.3f} | "
              f"{_fmt(free, names)} |", flush=True)
    print("\nThe diagnosis's 5-minute grid\n")
    print(head.format("grid and step"))
    print("| --- | --- | --- | --- | --- |")
    for label, one, free in diagnosis_grid(weather, args.h, model, gh):
        print(f"| {label} | {one.worst:.3f} | {_fmt(one, names)} | {free.worst:.3f} | "
              f"{_fmt(free, names)} |", flush=True)
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

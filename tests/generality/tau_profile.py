"""Why a start is found where it is (docs/effects.md, "Start times and the judge's power"): for
one dev case and one effect, the *joint* τ profile (at each start on a grid, base parameters and
amplitude refitted by Levenberg–Marquardt on all the data, as ``effect_fit.fit_effect`` refits
them), the start the search reports, and the calibrated base's mean multiple-shooting residual
per day on the case and on the same window without the change. When the profile's own minimum
is far from the truth, no search on it finds the truth: the objective, not the search, decides.
Never the held-out generator.

    python tests/generality/tau_profile.py twonode/autumn/drift [--effect sensor_drift]
    python tests/generality/tau_profile.py --synthetic   # the same search on model-made data
    python tests/generality/tau_profile.py --inject twonode/autumn/none  # a ramp added

``--inject``: the case is an effect-free window; a 0.5 K d-1 ramp is added to its reading from
``INJECT_DAYS`` (as the suite's drift: the reading only) and the start the search finds is
printed, with the base refitted (as reported) and held as calibrated on C (the first τ scan):
the method's share of a start error (calibration part overlapping the change, the refit, the
grid) against the base's (docs/effects.md, "The drift's start (issue 10, third look)").

``--synthetic``: 8 days made by the structured prototype itself (so the base is right) with a
0.5 K d-1 drift from day 3.4, plus a slow base error after the start (a 2-day Gaussian bump of
the reading, peak 1.6 d after it, of ±0.3, 0.6, 0.9 K: the size of the prototype's day-scale
error on the suite's windows): how far the search's reported start moves with it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import Case, case_series  # noqa: E402
from tests.generality.generators import CHANGE_DAY, EXPECTED, HELD_OUT  # noqa: E402

DAY = 86400.0
PROFILE_STEP_S = 6 * 3600.0
PROFILE_SPAN_S = 3 * DAY
INJECT_DAYS = (CHANGE_DAY - 2.0, CHANGE_DAY, CHANGE_DAY + 2.0)
"""``--inject``: ramp starts inside C, at the suite's change day (0.6 d before C ends), and
wholly inside the held-out half."""


def _setup(label: str, ramp: tuple[float, float] | None = None) -> tuple:
    """(search context, greenhouse, calibrated base, its parameters, samples) of one case, as
    ``diagnose`` builds them (split 0.5, seed 0); ``ramp`` (start day, rate [K d-1]) is added
    to the inside reading first (the suite's drift: the reading only, RH untouched)."""
    from gateway.diagnose import search

    g, w, k = label.split("/")
    if g in HELD_OUT:
        raise SystemExit(f"{g} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = case_series(Case("diagnose", g, w, k), Path(tmp))
    if ramp is not None:
        sec = (series.time - series.time[0]).astype("timedelta64[s]").astype(float)
        series.columns["t_in"] = (series.columns["t_in"]
                                  + ramp[1] * np.maximum(sec - ramp[0] * DAY, 0.0) / DAY)
    start = search.prepare(series, gh, model, 0.5, 0)
    return start.state.ctx, gh, start.state.model0, start.theta, len(start.coarse)


def daily_residual(label: str) -> dict[int, float]:
    """Mean multiple-shooting residual (prediction − reading) [K] of the calibrated base, per
    day of the data (windows by their start)."""
    ctx, _, model0, theta, n = _setup(label)
    shoot = ctx.shooting(model0, [(0, n)])
    r = np.nanmean(shoot.residual(theta[None])[0], axis=1)
    day = np.floor(ctx.x["_index"][shoot.starts] / DAY).astype(int)
    return {int(d): float(np.mean(r[day == d])) for d in np.unique(day)}


def joint_profile(label: str, effect: str) -> tuple[list[tuple[float, float, float]], float]:
    """([(τ − truth [d], ΔBIC against the base, amplitude)], reported τ − truth [d])."""
    from gateway.diagnose import effect_fit
    from gateway.diagnose.base import carry, free_parameters
    from gateway.diagnose.bic import delta_bic, effective_samples
    from gateway.diagnose.effects import EFFECTS, compose
    from gateway.diagnose.fit import fit_lm

    ctx, gh, model0, theta, n = _setup(label)
    e = EFFECTS[effect]
    new = compose(model0, [e], gh, ctx.duration)
    shoot = ctx.shooting(new, [(0, n)])
    th = carry(theta, model0, new, gh)
    sse0, npair = shoot.sse(th[None])
    ne = effective_samples(npair, ctx.dt)
    jt, ja = new.index(e.tau_name), new.index(e.amp_name)
    lo, hi = new.bounds(gh)
    truth = CHANGE_DAY * DAY
    first = 0.0 if e.from_start else effect_fit.COARSE_TAU_S
    out = []
    for tau in np.arange(max(first, truth - PROFILE_SPAN_S), min(ctx.last, truth + PROFILE_SPAN_S)
                         + 1.0, PROFILE_STEP_S):
        trial = th.copy()
        trial[jt] = tau
        trial = fit_lm(shoot, trial, free_parameters(new), lo, hi, effect_fit.REFIT_LM_ITERATIONS)
        sse = float(shoot.sse(trial[None])[0][0])
        out.append(((tau - truth) / DAY, delta_bic(sse, float(sse0[0]), ne, 2), float(trial[ja])))
    fitted = effect_fit.fit_effect(ctx, new, model0, theta, e, [(0, n)], latest=False).theta
    return out, (float(fitted[jt]) - truth) / DAY


def injected_drift_start(label: str, day: float, rate: float = 0.5) -> tuple[float, ...]:
    """A ``rate`` K d-1 ramp from ``day`` added to the reading of ``label`` (an effect-free dev
    window): (start − truth [h], rate found) of the search's fit on all the data
    (``effect_fit.fit_effect``, the reported start), then the same of the first τ scan alone (the
    base held as calibrated on C). Where the ramp starts and whether the base is refitted are
    what move the start if the method, not the base's error, misplaces it."""
    from gateway.diagnose import effect_fit
    from gateway.diagnose.base import carry
    from gateway.diagnose.effects import EFFECTS, compose

    ctx, gh, m0, th0, n = _setup(label, (day, rate))
    e = EFFECTS["sensor_drift"]
    m = compose(m0, [e], gh, ctx.duration)
    jt, ja = m.index(e.tau_name), m.index(e.amp_name)
    th = effect_fit.fit_effect(ctx, m, m0, th0, e, [(0, n)], latest=False).theta
    sc = effect_fit.scan(ctx.shooting(m, [(0, n)]), carry(th0, m0, m, gh), e, ctx.last, [(0, n)],
                      latest=False)
    return ((th[jt] - day * DAY) / 3600.0, float(th[ja]),
            (sc.taus[sc.best] - day * DAY) / 3600.0, float(sc.amps[sc.best]))


def synthetic_drift_start(bump: float, seed: int = 3, start_day: float = 3.4) -> float:
    """Reported start − truth [h] of a 0.5 K d-1 drift from ``start_day`` on 8 days of 5-minute
    data made by the structured prototype at its default parameters (day-to-day weather from
    ``seed``, reading noise 0.08 K), the reading lowered by a Gaussian bump of ``bump`` K
    (σ 0.6 d) centred 1.6 d after the start, searched as ``diagnose`` does (split 0.5, base held at the
    truth before the search)."""
    from gateway.diagnose import effect_fit
    from gateway.diagnose.effects import EFFECTS, compose
    from gateway.diagnose.fit import drivers
    from gateway.diagnose.structure import structure
    from gateway.greenhouse import load_greenhouse
    from gateway.model import build_model
    from gateway.series import Series

    gh = load_greenhouse("biskra-prototype")
    m0 = structure(build_model("prototype", gh), gh, False)
    n, dt = 8 * 288, 300.0
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    day = t / DAY
    daily = np.repeat(np.arange(9), 288)[:n]
    cols = {"t_out": 10 + 5 * np.sin(2 * np.pi * (day % 1 - 0.3)) + rng.normal(0, 3, 9)[daily],
            "rh_out": np.full(n, 70.0), "rh_in": np.full(n, 60.0), "t_in": np.full(n, 12.0),
            "i_glob": np.maximum(0, 600 * np.sin(2 * np.pi * (day % 1 - 0.25)))
            * rng.uniform(0.2, 1.0, 9)[daily], "wind": rng.uniform(0.5, 6.0, 9)[daily]}
    series = Series(np.datetime64("2020-01-01T00:00:00") + t.astype("timedelta64[s]"), dt, cols)
    x = drivers(series, gh)
    e = EFFECTS["sensor_drift"]
    m = compose(m0, [e], gh, float(x["_index"][-1]))
    truth, tau = m.defaults(gh), start_day * DAY
    truth[m.index(e.amp_name)], truth[m.index(e.tau_name)] = 0.5, tau
    x["t_in"] = (m.free_run(truth[None], x, gh, dt)[0] + rng.normal(0, 0.08, n)
                 - bump * np.exp(-0.5 * ((day - start_day - 1.6) / 0.6) ** 2))
    ctx = effect_fit.Context(x, gh, dt, float(x["_index"][-1]), 72, n // 2)
    fitted = effect_fit.fit_effect(ctx, m, m0, m0.defaults(gh), e, [(0, n)], latest=False).theta
    return (float(fitted[m.index(e.tau_name)]) - tau) / 3600.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("case", nargs="?", help="generator/window/kind")
    ap.add_argument("--effect", help="library effect (default: the one that names the kind)")
    ap.add_argument("--synthetic", action="store_true", help="model-made data (docstring)")
    ap.add_argument("--inject", action="store_true",
                    help="case = an effect-free window: a 0.5 K d-1 ramp added from days "
                         f"{INJECT_DAYS} (docstring)")
    a = ap.parse_args(argv)
    if a.inject and a.case:
        print("ramp from day | start − truth [h], rate [K d-1]: search (base refitted) | "
              "first scan (base held)")
        for day in INJECT_DAYS:
            err, rate, err0, rate0 = injected_drift_start(a.case, day)
            print(f"  {day:4.1f} | {err:+6.1f} h {rate:.3f} | {err0:+6.1f} h {rate0:.3f}",
                  flush=True)
        return 0
    if a.synthetic:
        print("base error bump [K] (reading lowered) | drift start found − truth [h]")
        for bump in (0.0, 0.3, -0.3, 0.6, -0.6, 0.9, -0.9):
            print(f"  {bump:+.1f} | {synthetic_drift_start(bump):+.1f}")
        print("drift start day (calibration part ends at day 4) | start found − truth [h]")
        for day in (1.4, 3.4, 5.4):
            print(f"  {day:.1f} | {synthetic_drift_start(0.0, start_day=day):+.1f}")
        return 0
    if not a.case:
        ap.error("a case is required (or --synthetic)")
    g, w, k = a.case.split("/")
    effect = a.effect or sorted(EXPECTED[k])[0]
    prof, reported = joint_profile(a.case, effect)
    best = min(prof, key=lambda r: r[1])
    print(f"{a.case} {effect}: joint profile minimum at {best[0]:+.2f} d, search reports "
          f"{reported:+.2f} d (start − truth)")
    for dd, dbic, amp in prof:
        print(f"  {dd:+6.2f} d  ΔBIC {dbic:8.1f}  amplitude {amp:+.3f}")
    case, free = daily_residual(a.case), daily_residual(f"{g}/{w}/none")
    print("base multiple-shooting residual per day [K], this case | effect-free window:")
    for d in case:
        print(f"  day {d:2d}  {case[d]:+6.2f} | {free.get(d, float('nan')):+6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Does the calibrated base carry over to the held-out part? One suite case, diagnosed with the
switches given: the base structure chosen on the inner split, the base parameters (those on a
bound marked), the base's free-run residual (measured − model) on the calibration part and on
the held-out part by night and day, per day, and every candidate the judge saw with its p
against the model before and against the reference (docs/effects.md, "Why the freer base gives
twonode winter a heater"). Never the held-out generator.

    python tests/generality/base_carry.py twonode/winter/none --seed 2 \\
        [--set base.NIGHT_SKY_IN_BASE=True --set judge.REFERENCE_TEST=True]
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import Case, case_series  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402

NIGHT_W_M2 = 5.0
"""Outside radiation below which a row counts as night [W m-2] (the night heater's own)."""


def at_bounds(names: list[str], theta: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              rtol: float = 1e-3) -> dict[str, str]:
    """Parameters on a bound of their box: name → "lower" / "upper" (within ``rtol`` of the
    box's width)."""
    out = {}
    for j, name in enumerate(names):
        tol = rtol * max(float(hi[j] - lo[j]), 1e-300)
        if theta[j] - lo[j] <= tol:
            out[name] = "lower"
        elif hi[j] - theta[j] <= tol:
            out[name] = "upper"
    return out


def split_stats(r: np.ndarray, night: np.ndarray) -> dict[str, tuple[float, float]]:
    """(mean, MAE) [K] of the residual ``r`` by night and day, over its finite rows."""
    ok = np.isfinite(r)
    out = {}
    for label, m in (("night", night), ("day", ~night)):
        k = ok & m
        out[label] = (float(np.mean(r[k])), float(np.mean(np.abs(r[k])))) if k.any() else (
            float("nan"), float("nan"))
    return out


def per_day(r: np.ndarray, first_row: int, dt: float) -> dict[int, float]:
    """Mean residual per day since the data's first row (rows ``first_row`` onwards on a grid
    of ``dt`` [s])."""
    day = ((np.arange(len(r)) + first_row) * dt // 86400.0).astype(int)
    ok = np.isfinite(r)
    return {int(d): float(np.mean(r[ok & (day == d)])) for d in np.unique(day[ok])}


def apply_settings(settings: list[str]) -> None:
    """``module.NAME=value`` (module under gateway.diagnose, value a Python literal) set before
    the diagnosis runs."""
    for item in settings:
        key, value = item.split("=", 1)
        module, name = key.rsplit(".", 1)
        mod = importlib.import_module(f"gateway.diagnose.{module}")
        if not hasattr(mod, name):
            raise SystemExit(f"gateway.diagnose.{module} has no {name}")
        setattr(mod, name, eval(value, {}))  # a literal: True, None, 0.2


def report(label: str, seed: int) -> str:
    """The figures of the module docstring for one case, as text."""
    from gateway.diagnose import diagnose
    from gateway.diagnose import judge as jd
    from gateway.diagnose.fit import drivers

    g, w, k = label.split("/")
    if g in HELD_OUT:
        raise SystemExit(f"{g} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = case_series(Case("diagnose", g, w, k, seed), Path(tmp))
        d = diagnose(series, gh, model)
    lines = [f"{label} seed {seed}"]
    for s in d.structure:
        lines.append(f"  {s['structure']:20s} kept {s['kept']!s:5s} C1 MSE {s['mse']:.4f} "
                     f"dBIC {s['delta_bic']:+.1f} C2 MSE {s['validation_mse']}")
    lo, hi = d.base_model.bounds(gh)
    edge = at_bounds(d.base_model.names, d.base_theta, lo, hi)
    lines.append("  base: " + ", ".join(
        f"{n} {v:.4g}" + (f" ({edge[n]} bound)" if n in edge else "")
        for n, v in zip(d.base_model.names, d.base_theta, strict=True)))
    x = drivers(series, gh)
    sf, dt = d.split_index, series.step
    night = x["i_glob"] < NIGHT_W_M2
    r_c = jd.calibration_free_run(d.base_model, d.base_theta, x, gh, dt, sf)
    r_h = d.measured[sf:] - d.pred_before["free_run"]
    for part, r, nt in (("calibration", r_c, night[:len(r_c)]), ("held-out", r_h, night[sf:])):
        st = split_stats(r, nt)
        lines.append(f"  {part}: night mean {st['night'][0]:+.3f} MAE {st['night'][1]:.3f}; "
                     f"day mean {st['day'][0]:+.3f} MAE {st['day'][1]:.3f} K")
    days = per_day(np.concatenate([r_c, r_h]), 0, dt)
    lines.append("  per day: " + " ".join(f"{dd}:{v:+.2f}" for dd, v in days.items()))
    lines.append(f"  base held-out MAE {d.before['free_run']['mae']:.3f} K, after "
                 f"{d.after['free_run']['mae']:.3f} K; findings "
                 f"{[(f.effect.name, f.start) for f in d.findings]}")
    for t in d.trials:
        lines.append(f"  round {t['round']} {t['effect']}: ok {t['ok']}, p {t['p']:.3f} "
                     f"(before), {t.get('p_days_reference', float('nan')):.3f} (reference), "
                     f"cut {t['cut']:+.2f}, against the reference {t['cut_reference']:+.2f}, "
                     f"halves {t['halves'][0]:+.3f}/{t['halves'][1]:+.3f} K, "
                     f"starts {[round(s / 86400.0, 2) for s in t['starts']]} d")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="+", help="generator/window/kind")
    ap.add_argument("--seed", type=int, default=1, help="the generators' sensor seed (1)")
    ap.add_argument("--set", action="append", default=[], metavar="MODULE.NAME=VALUE",
                    help="a switch under gateway.diagnose, e.g. base.NIGHT_SKY_IN_BASE=True")
    a = ap.parse_args(argv)
    apply_settings(a.set)
    for label in a.cases:
        print(report(label, a.seed), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

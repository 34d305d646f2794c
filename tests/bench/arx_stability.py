"""Why the RLS ARX baseline diverged on 1-minute data, side by side with the fix.

Runs gateway/estimate/arx.py's recursive least squares over a kit CSV three ways: the
conventional update (P ← (P − k φᵀP)/λ, as before the fix), the symmetric one (``arx.Rls``,
P kept symmetric), and the symmetric one with the forgetting defined per unit time
(λ = 0.995^(Δt / 300 s), the same ~16.7-h memory at any step; measured, not adopted). Prints,
after the first day: the condition number and smallest eigenvalue of P, the sample where P
first had a negative eigenvalue, the implied state multiplier of the forecast recursion
1 − θ₂ − θ₃ u − θ₄ (|·| > 1: the recursion amplifies), and the 15/30/60-min forecast MAE beside
persistence, with the forecast's guard (``arx.forecast_step``: the coefficient on T_in held in
[0, 1]) and without it, the plain recursion T + θ · φ(T) (docs/online-estimator.md, "The ARX
baseline on 1-minute data").

    .venv/bin/python tests/bench/arx_stability.py --data almeria_spring.csv \\
        --greenhouse almeria-palmerillas [--step 60]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the package, not tests/bench/gateway.py beside this script

from gateway.estimate import arx  # noqa: E402
from gateway.greenhouse import load_greenhouse  # noqa: E402
from gateway.model.drivers import prepare_drivers  # noqa: E402
from gateway.series import load_series  # noqa: E402


def run(x: dict, lam: float, symmetric: bool, every: int = 10) -> dict:
    """θ in force at each t and P's health sampled every ``every`` samples."""
    n = len(x["t_in"])
    phi = arx.regressors(x, x["t_in"], slice(0, n)) * arx.SCALE
    dy = np.append(np.diff(x["t_in"]), np.nan)
    w, p = np.zeros(len(arx.REGRESSORS)), arx.P0 * np.eye(len(arx.REGRESSORS))
    theta = np.full((n, len(w)), np.nan)
    mineig, cond, skew, first_negative, updates = [], [], [], None, 0
    for t in range(n):
        if updates:
            theta[t] = w * arx.SCALE
        if np.all(np.isfinite(phi[t])) and np.isfinite(dy[t]):
            pphi = p @ phi[t]
            gain = pphi / (lam + phi[t] @ pphi)
            w = w + gain * (dy[t] - phi[t] @ w)
            p = (p - np.outer(gain, pphi)) / lam
            if symmetric:
                p = 0.5 * (p + p.T)
            tr = np.trace(p)
            if tr > arx.P_MAX:
                p = p * (arx.P_MAX / tr)
            updates += 1
        if t % every == 0:
            eig = np.linalg.eigvalsh(0.5 * (p + p.T))
            mineig.append(eig[0])
            skew.append(np.linalg.norm(p - p.T) / np.linalg.norm(p))
            cond.append(abs(eig[-1]) / max(abs(eig[0]), 1e-300))
            if eig[0] < 0 and first_negative is None:
                first_negative = t
    return {"theta": theta, "mineig": np.array(mineig), "cond": np.array(cond),
            "skew": np.array(skew), "first_negative": first_negative}


def plain(x: dict, theta: np.ndarray, starts: np.ndarray, h: int) -> np.ndarray:
    """The unguarded recursion T[k+1] = T[k] + θ · φ(T[k]) (the forecast before the guard)."""
    t = x["t_in"][starts]
    for k in range(h):
        t = t + np.einsum("nj,nj->n", arx.regressors(x, t, starts + k), theta[starts])
    return t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="kit CSV")
    ap.add_argument("--greenhouse", required=True, help="preset name or TOML")
    ap.add_argument("--step", type=float, default=60.0, help="model step [s] (60)")
    a = ap.parse_args(argv)
    series = load_series(a.data, step=a.step)
    x = prepare_drivers(series, load_greenhouse(a.greenhouse))
    n, day = len(x["t_in"]), int(round(86400.0 / a.step))
    per_time = arx.FORGETTING ** (a.step / 300.0)
    for label, lam, sym in (("conventional", arx.FORGETTING, False),
                            ("symmetric (arx.Rls)", arx.FORGETTING, True),
                            (f"symmetric, λ per time ({per_time:.5f})", per_time, True)):
        r = run(x, lam, sym)
        th = r["theta"]
        mult = (1 - th[:, 1] - th[:, 2] * x["wind"] - th[:, 3])[day:]
        k = day // 10
        m = len(r["cond"]) if r["first_negative"] is None else r["first_negative"] // 10
        print(f"{label}: λ = {lam:.5f}; while P is PSD: cond(P) median {np.median(r['cond'][k:m]):.2g}, "
              f"max {np.max(r['cond'][k:m]):.2g}, asymmetry ‖P − Pᵀ‖/‖P‖ max "
              f"{np.max(r['skew'][:m]):.2g}; min eig(P) {np.min(r['mineig']):.3g}; first negative "
              f"eigenvalue at sample {r['first_negative']}"
              + ("" if r["first_negative"] is None else f" ({series.time[r['first_negative']]})"))
        print(f"  multiplier 1 − θ₂ − θ₃u − θ₄: min {np.nanmin(mult):.4g}, median "
              f"{np.nanmedian(mult):.4g}, max {np.nanmax(mult):.4g}; > 1 in "
              f"{np.nanmean(mult > 1) * 100:.1f} % of samples, |·| > 1 in "
              f"{np.nanmean(np.abs(mult) > 1) * 100:.1f} %")
        res = arx.ArxResult(th, np.zeros(n), 0)
        for minutes in (15, 30, 60):
            h = int(minutes * 60 / a.step)
            starts = np.arange(day, n - h)
            truth = x["t_in"][starts + h]
            err = np.abs(res.forecast(x, starts, h) - truth)
            unguarded = np.abs(plain(x, th, starts, h) - truth)
            pers = np.abs(x["t_in"][starts] - truth)
            print(f"  {minutes} min: MAE {np.nanmean(err):.4g} (max {np.nanmax(err):.3g}); "
                  f"unguarded {np.nanmean(unguarded):.4g} (max {np.nanmax(unguarded):.3g}); "
                  f"persistence {np.nanmean(pers):.3f}")
    return 0


if __name__ == "__main__":
    with np.errstate(all="ignore"):
        raise SystemExit(main())

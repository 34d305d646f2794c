"""Study: does an unseen vent controller explain the forecast errors? Tuning windows only.

The kept replays of ``tests/generality/forecasts.py --keep DIR`` (refsim and twonode: the
held-out generator's are never read) are scored with the current code, then five checks
of issue 10's idea that a vent controller proportional on T_in above a setpoint, which the kit
does not see, is what the 15-30-min forecasts miss:

1. ``residuals``: the correlation of the forecast error e = T_in[t + h] − f(t) at 15 and 30
   min with the controller's air-exchange signal F = σ(T − T_set) (T − T_out) at the start
   (``start``) and its change along the forecast, F(f) − F(T_in[t]) (``delta``), the best
   T_set of 16-30 °C per window; and how much of e a least-squares fit on (1, f − T_in) plus
   F and ΔF explains beyond (1, f − T_in) alone, in sample (an upper bound of what a linear
   correction with these columns could do).
2. ``oracle``: the incremental controller term put into the ``adaptive_kf`` forecast (from the
   start, the added exchange g [σ(T − T_set) − σ(T_0 − T_set)] relaxes the forecast toward
   T_out: the estimator's C_loss already holds the exchange at the start), then ``combined``
   and ``corrected`` recomputed; the best (g, T_set) of a grid per window, chosen on the
   window itself: an optimistic bound of what the term can give the forecasts.
3. ``bound``: an in-sample least-squares fit of T_in[t + h] − T_in[t] on every forecast
   member (adaptive, adaptive + KF, ARX, constant, corrected, each minus T_in), the correction's
   drivers and four lags of T_in: how far a linear post-processing could go.
4. ``cost``: the estimator's wall time per update with and without the term
   (gateway/model/vent_control.py), stepped in turn on refsim summer's first two days.
5. ``noise``: whether the start state (the DHT22's noise) or the model errs (``noise``'s doc).

    nice -n 5 .venv/bin/python tests/generality/vent_control_study.py out/fc [--checks ...]
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.estimate import correction  # noqa: E402
from gateway.estimate import replay as rp  # noqa: E402
from gateway.estimate import replay_forecasts as rf  # noqa: E402
from gateway.model.vent_control import soft_excess  # noqa: E402
from tests.generality.outlook_variants import tuning_replays  # noqa: E402

WARMUP = 86400.0
"""[s] day 1 is the estimator's warm-up, as in the suite."""
SETPOINTS = np.arange(16.0, 31.0, 2.0)
GAINS = (2e-5, 5e-5, 1e-4, 2e-4)
"""[s-1 K-1] of the oracle grid."""


def _starts(res, minutes: int) -> tuple[np.ndarray, np.ndarray]:
    f = res.horizons[minutes]
    s = f["target"] - int(round(minutes * 60.0 / res.dt))
    return s, s >= int(round(WARMUP / res.dt))


def _fit_mae(x: np.ndarray, y: np.ndarray) -> float:
    b, *_ = np.linalg.lstsq(x, y, rcond=None)
    return float(np.abs(y - x @ b).mean())


def residuals(kept) -> None:
    print("| window | h | forecast | MAE | best r (kind, T_set) | in-sample (1, f − T_in) | + F, ΔF |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for stem, res in kept:
        for minutes in (15, 30):
            f = res.horizons[minutes]
            s, keep = _starts(res, minutes)
            t_in, t_out, fc = res.x["t_in"][s], res.x["t_out"][s], f["adaptive_kf"]
            for name in ("adaptive_kf", "corrected"):
                e = f["measured"] - f[name]
                ok = keep & np.isfinite(e) & np.isfinite(fc)
                best, fits = (0.0, "", 0.0), []
                base = np.c_[np.ones(ok.sum()), (fc - t_in)[ok]]
                for ts in SETPOINTS:
                    f0 = soft_excess(t_in - ts) * (t_in - t_out)
                    f1 = soft_excess(fc - ts) * (fc - t_out)
                    for kind, col in (("start", f0), ("delta", f1 - f0)):
                        if np.std(col[ok]) > 1e-9:
                            r = float(np.corrcoef(e[ok], col[ok])[0, 1])
                            if abs(r) > abs(best[0]):
                                best = (r, kind, ts)
                    fits.append(_fit_mae(np.c_[base, f0[ok], (f1 - f0)[ok]], e[ok]))
                print(f"| {stem} | {minutes} | {name} | {np.abs(e[ok]).mean():.3f} | {best[0]:+.2f} "
                      f"({best[1]}, {best[2]:.0f} °C) | {_fit_mae(base, e[ok]):.3f} | {min(fits):.3f} |")


def _kf_with_controller(res, starts: np.ndarray, steps: int, gain: float, t_set: float) -> np.ndarray:
    """``adaptive_kf`` with the incremental controller exchange (module docstring, 2)."""
    m, x, kf = res.model, res.x, res.filtered
    rho = kf.settings.per_step(res.dt)[0]
    p = m.columns(res.theta[starts])
    t = starts[:, None]
    state = kf.t_hat[starts][:, None]
    b, t0 = kf.b_hat[starts][:, None], state.copy()
    step = m.stepper(p, x, m.capacity(res.gh), res.dt)
    t_out = x["t_out"]
    for k in range(steps):
        state = step(state, t + k) + res.dt * b * rho**k
        out = t_out[np.minimum(t + k + 1, len(t_out) - 1)]
        extra = gain * (soft_excess(state - t_set) - soft_excess(t0 - t_set))
        state = out + (state - out) * np.exp(-extra * res.dt)
    return m.reading(p, x, state, t + steps)[:, 0]


def _rescored(res, reach, gain: float, t_set: float, kf0: dict) -> dict:
    for minutes, steps in reach.items():
        f = res.horizons[minutes]
        starts = f["target"] - steps
        f["adaptive_kf"] = (_kf_with_controller(res, starts, steps, gain, t_set) if gain > 0
                            else kf0[minutes])
        f["combined"] = rf._combined(res, starts, steps, [f["adaptive_kf"], f["arx"]])
    rf._corrected(res, reach, "")
    return rp.report(res, warmup=int(round(WARMUP / res.dt)))["horizons"]


def oracle(kept) -> None:
    print("| window | (g [s-1 K-1], T_set) | adaptive + KF 15/30/60 | corrected 15/30/60 |")
    print("| --- | --- | --- | --- |")
    for stem, res in kept:
        reach = rp.steps_of(rp.HORIZONS, res.dt)
        kf0 = {m: res.horizons[m]["adaptive_kf"].copy() for m in reach}
        rows = []
        for gain, ts in [(0.0, 0.0), *itertools.product(GAINS, SETPOINTS)]:
            hs = _rescored(res, reach, gain, ts, kf0)
            kf = [hs[str(m)]["adaptive_kf"]["mae"] for m in reach]
            co = [hs[str(m)]["corrected"]["mae"] for m in reach]
            rows.append((sum(co), gain, ts, kf, co))
        best = min(rows[1:])
        for label, (_, gain, ts, kf, co) in (("none", rows[0]), ("best", best)):
            where = "none" if gain == 0 else f"{gain:.0e}, {ts:.0f} °C"
            print(f"| {stem} ({label}) | {where} | {' / '.join(f'{v:.3f}' for v in kf)} | "
                  f"{' / '.join(f'{v:.3f}' for v in co)} |", flush=True)


def bound(kept) -> None:
    print("| window | h | corrected | in-sample linear fit on members, drivers, lags | persistence |")
    print("| --- | --- | --- | --- | --- |")
    for stem, res in kept:
        for minutes in (15, 30):
            f = res.horizons[minutes]
            s, keep = _starts(res, minutes)
            t_in = res.x["t_in"][s]
            w = 2.0 * np.pi * correction.hour_of_day(res.time[s]) / 24.0
            cols = [f[k] - t_in for k in ("adaptive", "adaptive_kf", "arx", "constant", "corrected")]
            lags = [t_in - res.x["t_in"][np.maximum(s - lag, 0)] for lag in (1, 2, 3, 6)]
            x = np.c_[np.ones_like(t_in), *cols, res.x["i_glob"][s] / 1e3,
                      (res.x["t_out"][s] - t_in) / 10.0, np.sin(w), np.cos(w), (t_in - 20.0) / 10.0,
                      *lags]
            y = f["measured"] - t_in
            ok = keep & np.all(np.isfinite(x), axis=1) & np.isfinite(y)
            print(f"| {stem} | {minutes} | {np.abs(f['measured'] - f['corrected'])[ok].mean():.3f} | "
                  f"{_fit_mae(x[ok], y[ok]):.3f} | {np.abs(y[ok]).mean():.3f} |")


def cost(_kept, rows: int = 576, rounds: int = 3) -> None:
    """Wall time of ``OnlineEstimator.update`` with and without the term on the first two days
    of refsim summer, the two estimators stepped in turn (the same load on both)."""
    import tempfile
    import time

    from gateway.estimate.online import OnlineEstimator
    from gateway.model.prototype import build_prototype
    from tests.generality.cases import Case, case_series

    with tempfile.TemporaryDirectory() as tmp:
        _, gh, _, series = case_series(Case("forecast", "refsim", "summer"), Path(tmp))
    names = list(series.columns)
    samples = [{c: float(series.columns[c][t]) for c in names} for t in range(rows)]
    ms: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(rounds):
        est = {vc: OnlineEstimator(build_prototype(gh, vc), gh, dt=series.step, seed=0)
               for vc in ms}
        for t, sample in enumerate(samples):
            for vc, e in est.items():
                t0 = time.perf_counter()
                e.update(sample, time=series.time[t])
                ms[vc].append((time.perf_counter() - t0) * 1e3)
    for vc, v in ms.items():
        print(f"| {'with' if vc else 'without'} the term | median {np.median(v):.2f} ms | "
              f"mean {np.mean(v):.2f} ms | p95 {np.percentile(v, 95):.2f} ms |")


def noise(kept) -> None:
    """Is the start state the problem (the DHT22's noise) or the model? Per 3-hour block of the
    UTC day: the one-step residual's mean |e| and lag-1 autocorrelation (white sensor noise
    gives −0.5, a model error that persists gives > 0) and the reading's white-noise level from
    its second differences, sd(Δ²T) / √6 (the DHT22 with its 0.1-K step: ≈ 0.09 K)."""
    print("| window | " + " | ".join(f"{a:02d}-{a + 3:02d} h" for a in range(0, 24, 3)) + " |")
    print("| --- " * 9 + "|")
    for stem, res in kept:
        y, hour = res.measured, correction.hour_of_day(res.time)
        e = y - res.adaptive
        d2 = np.full_like(y, np.nan)
        d2[1:-1] = y[2:] - 2.0 * y[1:-1] + y[:-2]
        after = np.arange(len(y)) >= int(round(WARMUP / res.dt))
        cells = []
        for a in range(0, 24, 3):
            m = after & (hour >= a) & (hour < a + 3)
            em = np.where(m, e, np.nan)
            ok = np.isfinite(em[1:]) & np.isfinite(em[:-1])
            rho = float(np.corrcoef(em[1:][ok], em[:-1][ok])[0, 1])
            sd = float(np.nanstd(np.where(m, d2, np.nan))) / np.sqrt(6.0)
            cells.append(f"{np.nanmean(np.abs(em)):.2f} / {rho:+.2f} / {sd:.2f}")
        print(f"| {stem} | " + " | ".join(cells) + " |")


CHECKS = {"residuals": residuals, "oracle": oracle, "bound": bound, "cost": cost, "noise": noise}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kept", help="the directory of tests/generality/forecasts.py --keep")
    ap.add_argument("--checks", default=",".join(CHECKS), help=f"of {', '.join(CHECKS)}")
    a = ap.parse_args(argv)
    kept = tuning_replays(a.kept)
    for name in a.checks.split(","):
        print(f"\n{name} ({len(kept)} tuning windows)\n")
        CHECKS[name](kept)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

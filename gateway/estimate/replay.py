"""Replay of recorded data through the online estimator, sample by sample, and its report.

``replay`` feeds every row of a series to :class:`OnlineEstimator.update` exactly as the live
gateway does, records what it predicted, then computes, after the loop and vectorised:

- the "constant" baseline: the same model with the starting parameters held fixed (the
  thesis's offline-calibrated model), one step ahead from the measured state;
- persistence: T_in[t + 1] = T_in[t];
- the plain adaptive linear baseline (``arx``, gateway/estimate/arx.py): recursive least
  squares on a linear model of dT_in with the same kit inputs, one step and h steps ahead;
- ``adaptive_kf``: the adaptive model with a Kalman-filtered disturbance state
  (gateway/estimate/disturbance.py): the start state filtered of the sensor's noise and an
  estimated heating rate the model lacks, decaying over the horizon;
- forecasts h = 15, 30, 60 min ahead from every start t with the parameters in force at t
  (``Model.forecast``; gateway/estimate/replay_forecasts.py, each kind one run to the longest
  horizon, read at each), against persistence T_in[t + h] = T_in[t] and the ARX baseline, twice:
  with the weather that was later measured (model skill: ``adaptive``, ``adaptive_kf``,
  ``constant``, ``arx``; the inside readings a model reads besides its state, such as the
  transpiration's vapour pressure, held at the start: horizon.measured_weather_blocks) and
  with a causal weather outlook (what the live gateway can do:
  ``adaptive_outlook``, ``adaptive_kf_outlook``, ``arx_outlook``; gateway/estimate/outlook.py,
  default ``clear-sky-trend`` when the greenhouse has a ``[site]``).

All figures of one comparison use the same samples (every prediction finite).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.estimate import arx as arx_baseline
from gateway.estimate import disturbance
from gateway.estimate.horizon import HorizonDrivers, outlook_drivers
from gateway.estimate.online import GroupSettings, OnlineEstimator
from gateway.estimate.online_output import Counters
from gateway.estimate.outlook import Outlook, default_outlook, make_outlook
from gateway.estimate.replay_forecasts import score_forecasts
from gateway.estimate.sample_check import stuck_limit
from gateway.greenhouse import Greenhouse
from gateway.metrics import metrics
from gateway.model.model import Model
from gateway.model.terms import SUN_THRESHOLD
from gateway.series import Series

HORIZONS = (15, 30, 60)
"""Forecast horizons [min] of the report (reached in whole model steps)."""
FORECASTS = ("adaptive", "adaptive_kf", "combined", "corrected", "constant", "arx", "persistence",
             "adaptive_outlook", "adaptive_kf_outlook", "combined_outlook", "corrected_outlook",
             "arx_outlook")
"""Forecasts of the report, in order: measured weather (model skill), then with the outlook."""


@dataclass
class ReplayResult:
    """Everything one replay produced, aligned on the series' time grid (length T)."""

    model: Model
    gh: Greenhouse
    time: np.ndarray
    dt: float
    x: dict[str, np.ndarray]  # checked drivers the estimator saw, per sample
    adaptive: np.ndarray  # one-step prediction of T_in[t] made at t - 1 (NaN at 0)
    constant: np.ndarray  # same with theta0 held fixed
    theta: np.ndarray  # (T, k) parameters in force after the update at t
    theta0: np.ndarray
    step_ms: np.ndarray  # wall time of each update [ms]
    counters: Counters
    settings: tuple[GroupSettings, ...]
    horizons: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    rad_adaptive: np.ndarray | None = None
    rad_constant: np.ndarray | None = None
    arx: arx_baseline.ArxResult | None = None
    filtered: disturbance.FilterResult | None = None  # the disturbance filter (adaptive_kf)
    ahead: HorizonDrivers | None = None  # the outlook's driver blocks, one per start

    @property
    def measured(self) -> np.ndarray:
        return self.x["t_in"]

    def radiation(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(adaptive, constant) predictions of i_in [W m-2]; None without a radiation sub-model."""
        if self.rad_adaptive is None:
            return None
        if self.rad_constant is None:  # replay() sets both together
            raise ValueError("a replay result with an adaptive i_in prediction but no constant one")
        return self.rad_adaptive, self.rad_constant

    @property
    def persistence(self) -> np.ndarray:
        out = np.full_like(self.measured, np.nan)
        out[1:] = self.measured[:-1]
        return out


def replay(
    model: Model,
    series: Series,
    gh: Greenhouse,
    theta0: np.ndarray | None = None,
    settings: Sequence[GroupSettings] | None = None,
    seed: int | None = 0,
    horizons: Sequence[int] = HORIZONS,
    progress: Callable[[int], None] | None = None,
    outlook: Outlook | None = None,
    score: bool = True,
) -> ReplayResult:
    """Run the estimator over ``series`` row by row; ``progress(rows_done)`` every 100 rows.

    ``outlook``: the weather outlook of the live-style forecasts (default: ``clear-sky-trend``
    for a greenhouse with a ``[site]``, else ``hold-latest``). ``score``: False leaves out what
    is made from the loop's record afterwards (``score_forecasts``: the ARX baseline, the
    disturbance filter, the forecasts and their correction), for a caller that reads only the
    estimator's run (``vsensor.adaptive.run_adaptive``: ~8 % of its time went there)."""
    est = OnlineEstimator(model, gh, theta0, settings, dt=series.step, seed=seed,
                          stuck_samples=stuck_limit(series.step, series.native_step))
    n, k = len(series), len(model.names)
    adaptive = np.full(n, np.nan)
    theta = np.full((n, k), np.nan)
    step_ms = np.full(n, np.nan)
    names = list(series.columns)
    cols = [series.columns[c] for c in names]
    x: dict[str, np.ndarray] = {}
    clock = time.perf_counter
    for t in range(n):
        sample = {c: float(v[t]) for c, v in zip(names, cols, strict=True)}
        t0 = clock()
        pred = est.update(sample, time=series.time[t])
        step_ms[t] = (clock() - t0) * 1e3
        if t + 1 < n and pred.t_in is not None:
            adaptive[t + 1] = pred.t_in
        theta[t] = pred.theta
        for key, value in est.last_row.items():
            if key not in x:
                x[key] = np.full(n, np.nan)
            x[key][t] = value
        if progress is not None and (t + 1) % 100 == 0:
            progress(t + 1)
    theta0_used = est.theta0
    constant = model.one_step(theta0_used[None, :], x, gh, series.step)[0]
    result = ReplayResult(
        model=model, gh=gh, time=series.time, dt=series.step, x=x, adaptive=adaptive,
        constant=constant, theta=theta, theta0=theta0_used, step_ms=step_ms,
        counters=est.counters, settings=est.settings,
    )
    reach = steps_of(horizons, series.step) if score else {}
    if reach:
        if outlook is None:
            outlook = make_outlook(default_outlook(gh), gh)
        result.ahead = outlook_drivers(outlook, x, list(series.columns), series.time, series.step,
                                       gh, np.arange(max(n - 1, 0)), max(reach.values()))
    if score:
        score_forecasts(result, reach)
    if model.radiation is not None and "i_in" in x and np.isfinite(x["i_in"]).any():
        j = model.index(model.radiation.parameter.name)
        # i_in at t simulated from i_glob at t with c_tsw as estimated up to t - 1 (III.35)
        c_prev = np.concatenate([[theta0_used[j]], theta[:-1, j]])
        result.rad_adaptive = model.radiation.predict(c_prev[None, :], x)[0]
        result.rad_constant = model.radiation.predict(np.array([[theta0_used[j]]]), x)[0]
    return result


def steps_of(horizons: Sequence[int], dt: float) -> dict[int, int]:
    """Horizon [min] → model steps of ``dt`` [s]; a horizon the step cannot reach is left out."""
    return {int(m): int(m * 60.0 / dt) for m in horizons
            if m * 60.0 / dt >= 1 and float(m * 60.0 / dt).is_integer()}


def _common(measured: np.ndarray, preds: Mapping[str, np.ndarray], keep: np.ndarray) -> dict:
    ok = keep & np.isfinite(measured)
    for p in preds.values():
        ok &= np.isfinite(p)
    return {name: metrics(measured[ok], p[ok]) for name, p in preds.items()}


def report(result: ReplayResult, warmup: int = 0) -> dict:
    """The JSON report of the replay; the first ``warmup`` samples are left out of every metric."""
    n = len(result.measured)
    keep = np.arange(n) >= warmup
    one_step = {"adaptive": result.adaptive, "constant": result.constant,
                "persistence": result.persistence}
    if result.arx is not None:
        one_step["arx"] = result.arx.one_step
    one = _common(result.measured, one_step, keep)
    horizons = {}
    for h, f in result.horizons.items():
        steps = int(round(h * 60.0 / result.dt))
        keep_h = f["target"] >= warmup + steps  # the start, not only the target, is after warm-up
        names = [k for k in FORECASTS if k in f]
        horizons[str(h)] = _common(f["measured"], {k: f[k] for k in names}, keep_h)
    radiation = None
    if (rad := result.radiation()) is not None:
        sunlit = keep & (result.x["i_glob"] > SUN_THRESHOLD)
        radiation = _common(result.x["i_in"], {"adaptive": rad[0], "constant": rad[1]}, sunlit)
    c = result.counters
    ms = result.step_ms[np.isfinite(result.step_ms)]
    return {
        "model": result.model.name,
        "samples": c.samples,
        "skipped": c.faulty_samples,
        "metrics": one,
        "horizons": horizons,
        "outlook": result.ahead.outlook if result.ahead is not None else None,
        "radiation": radiation,
        "step_ms": {
            "median": float(np.median(ms)) if ms.size else None,
            "p95": float(np.percentile(ms, 95)) if ms.size else None,
            "max": float(ms.max()) if ms.size else None,
        },
        "faults": dict(sorted(c.faults.items())),
        "estimations": {"done": dict(c.estimated), "skipped_incomplete_window": dict(c.skipped)},
        "no_prediction": c.no_prediction,
        "warmup_samples": warmup,
        "settings": [
            {"output": g.output, "parameters": list(g.parameters), "window": g.window,
             "every": g.every, "iterations": g.iterations, "bats": g.bats, "prior": g.prior}
            for g in result.settings
        ],
        "params": {
            "start": dict(zip(result.model.names, map(float, result.theta0), strict=True)),
            "end": dict(zip(result.model.names, map(float, result.theta[-1]), strict=True)),
        },
    }


def write_predictions(result: ReplayResult, path: str | Path) -> None:
    """CSV: time, measured and predicted values, every parameter and every heat flux [W m-2].

    Fluxes are evaluated along the measured temperature with the parameters in force at t - 1
    (those that made the prediction of t).
    """
    model = result.model
    n = len(result.measured)
    theta_prev = np.vstack([result.theta0[None, :], result.theta[:-1]])
    t_state = np.where(np.isfinite(result.measured), result.measured, result.adaptive)
    fluxes = model.fluxes(theta_prev, result.x, t_state)
    cols: dict[str, np.ndarray] = {
        "t_in_measured": result.measured,
        "t_in_adaptive": result.adaptive,
        "t_in_constant": result.constant,
        "t_in_persistence": result.persistence,
    }
    if (rad := result.radiation()) is not None:
        cols["i_in_measured"] = result.x["i_in"]
        cols["i_in_adaptive"], cols["i_in_constant"] = rad
    for j, name in enumerate(model.names):
        cols[name] = result.theta[:, j]
    for name, q in fluxes.items():
        cols[name] = np.broadcast_to(q, (n,))
    header = ["time", *cols]
    stamps = np.datetime_as_string(result.time, unit="s")
    lines = [",".join(header)]
    arrays = list(cols.values())
    for i in range(n):
        cells = [f"{stamps[i]}Z"] + ["" if not np.isfinite(a[i]) else f"{a[i]:.6g}" for a in arrays]
        lines.append(",".join(cells))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")

"""A replay's forecasts, made after the estimator's loop from what it recorded (``score_forecasts``,
gateway/estimate/replay.py describes each forecast).

Every kind of forecast is one run from every start to the longest horizon, read at each horizon
on the way (``Model.forecast_each``, ``disturbance.forecast_each``, ``ArxResult.forecast_each``):
the run to a shorter horizon is the longer run's first steps, so the numbers are the same as a
run per horizon, bit for bit. A start's numbers do not depend on the other starts run beside it:
the steps are element-wise over the starts, and their reductions over the starts only choose
between paths that give the same numbers (the step's check for non-finite rates masks start by
start; the vent controller's skip when no start is sunlit leaves out a flux that is 0 for each
start anyway). The starts are the
shortest horizon's (every start with a finite reading and parameters, and a target in the
series); a longer horizon's are their first ones (those whose target is in the series), so each
horizon reads the first of the run's values. The runs of the last starts go on past the end of
the series: the drivers there are the last row's, as ``measured_weather_blocks`` holds them, and
no value read out comes from those steps (a start s is read at h only when s + h is a row).
What differs per horizon stays per horizon: the combination's and the correction's errors.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from gateway.estimate import arx as arx_baseline
from gateway.estimate import combination, correction, disturbance
from gateway.estimate.horizon import INSIDE_READINGS, measured_weather_blocks

if TYPE_CHECKING:
    from gateway.estimate.replay import ReplayResult


def score_forecasts(result: ReplayResult, reach: Mapping[int, int]) -> None:
    """After the estimator's loop: the ARX baseline, the disturbance filter and the forecasts
    (``reach``: horizon [min] → model steps) of ``result``, all from what the loop recorded (and
    ``result.ahead``, the outlook's blocks). A saved replay can be scored again with new code."""
    result.arx = arx_baseline.fit(result.x)
    result.filtered = disturbance.filter_series(result.model, result.theta, result.x, result.gh,
                                                result.dt)
    each = forecasts_each(result, list(reach.values()))
    result.horizons = {minutes: each[steps] for minutes, steps in reach.items()}
    for suffix in ("", "_outlook"):
        _corrected(result, reach, suffix)


def forecasts(result: ReplayResult, horizon: int) -> dict[str, np.ndarray]:
    """Forecasts of T_in[t + h] from every start t, h = ``horizon`` model steps (vectorised over
    the starts).

    Returns ``target`` (index t + h), ``measured``, ``persistence`` (T_in[t]) and forecasts
    over the starts: with the measured weather ``adaptive`` (parameters in force at t),
    ``constant`` (theta0), ``arx``, ``adaptive_kf`` (with the disturbance filter, when
    ``result.filtered`` is set); with the outlook (when ``result.ahead`` is set)
    ``adaptive_outlook``, ``adaptive_kf_outlook`` and ``arx_outlook``.
    """
    return forecasts_each(result, [horizon])[horizon]


def forecasts_each(result: ReplayResult,
                   horizons: Sequence[int]) -> dict[int, dict[str, np.ndarray]]:
    """{h: ``forecasts(result, h)``} for each of ``horizons`` [model steps]: each kind run once
    to the longest (the module docstring)."""
    todo = sorted(set(horizons))
    if not todo:
        return {}
    n = len(result.measured)
    starts = np.arange(0, max(n - todo[0], 0))
    ok = np.isfinite(result.measured[starts]) & np.all(np.isfinite(result.theta[starts]), axis=1)
    starts = starts[ok]
    runs = _runs(result, starts, todo)
    out = {}
    for h in todo:
        m = int(np.searchsorted(starts, n - h))  # the starts whose target t + h is a row
        s = starts[:m]
        f = {"target": s + h, "measured": result.measured[s + h]}
        f.update((kind, run[h][:m]) for kind, run in runs.items() if h in run)
        f["persistence"] = result.measured[s]
        f = {k: f[k] for k in _ORDER if k in f}
        for suffix in ("", "_outlook"):
            parts = (f"adaptive_kf{suffix}", f"arx{suffix}")
            if all(p in f for p in parts):
                f[f"combined{suffix}"] = _combined(result, s, h, [f[p] for p in parts])
        out[h] = f
    return out


_ORDER = ("target", "measured", "adaptive", "constant", "persistence", "arx", "adaptive_kf",
          "adaptive_outlook", "adaptive_kf_outlook", "arx_outlook")
"""The order of ``forecasts``'s keys (``combined`` and ``corrected`` follow)."""


def _runs(result: ReplayResult, starts: np.ndarray,
          horizons: list[int]) -> dict[str, dict[int, np.ndarray]]:
    """{kind: {h: (N,)}}: each kind's one run from ``starts`` (sorted) to the longest of
    ``horizons`` (sorted), read at each."""
    model, x, gh, dt = result.model, result.x, result.gh, result.dt
    theta = result.theta[starts]
    # the measured weather over the horizon, past the series' end its last row
    past = horizons[-1] - horizons[0]  # the rows the last start's run goes past the end
    x_on = {k: np.concatenate([v, np.repeat(v[-1:], past)]) for k, v in x.items()} if past else x
    # the inside readings the model reads besides its state (the Almería transpiration's
    # p_w,in, the soil) held at the start (gateway/estimate/horizon.py)
    wx, w_rows = x_on, starts
    if any(c in INSIDE_READINGS for c in model.requires if c != "t_in"):
        blocks = measured_weather_blocks(x, starts, horizons[-1])
        wx, w_rows = blocks.x, blocks.rows
    runs = {
        "adaptive": model.forecast_each(theta, wx, gh, dt, w_rows, horizons),
        "constant": model.forecast_each(np.repeat(result.theta0[None, :], len(starts), axis=0),
                                        wx, gh, dt, w_rows, horizons),
    }
    if result.arx is not None:
        runs["arx"] = result.arx.forecast_each(x_on, starts, horizons)  # T_in at the start only
    kf = result.filtered
    kf_start = None if kf is None else (kf.t_hat[starts], kf.b_hat[starts], kf.settings)
    if kf_start is not None:
        runs["adaptive_kf"] = disturbance.forecast_each(model, theta, wx, gh, dt, w_rows,
                                                        horizons, *kf_start)
    ahead = result.ahead
    near = [h for h in horizons if ahead is not None and h <= ahead.horizon]
    if ahead is not None and near:
        rows = ahead.rows[np.searchsorted(ahead.starts, starts)]
        runs["adaptive_outlook"] = model.forecast_each(theta, ahead.x, gh, dt, rows, near)
        if kf_start is not None:
            runs["adaptive_kf_outlook"] = disturbance.forecast_each(
                model, theta, ahead.x, gh, dt, rows, near, *kf_start)
        if result.arx is not None:
            runs["arx_outlook"] = result.arx.forecast_each(ahead.x, starts, near, rows)
    return runs


def _combined(result: ReplayResult, starts: np.ndarray, horizon: int,
              parts: Sequence[np.ndarray]) -> np.ndarray:
    """gateway/estimate/combination.py over the starts (mapped onto the series' time grid, where
    its causal window lives)."""
    n = len(result.measured)
    full = []
    for f in parts:
        a = np.full(n, np.nan)
        a[starts] = f
        full.append(a)
    window = max(int(round(combination.WINDOW_S / result.dt)), 1)
    named = {str(k): a for k, a in enumerate(full)}
    return combination.combine(named, result.measured, horizon, window)[starts]


def _corrected(result: ReplayResult, reach: Mapping[int, int], suffix: str) -> None:
    """``corrected{suffix}``: ``combined{suffix}`` with its online error correction
    (gateway/estimate/correction.py, the ARX stacked), on the series' grid, every horizon."""
    n = len(result.measured)
    combined: dict[int, np.ndarray] = {}
    arx: dict[int, np.ndarray] = {}
    starts: dict[int, np.ndarray] = {}
    ahead: dict[int, dict[str, np.ndarray]] = {}
    for minutes, steps in reach.items():
        f = result.horizons[minutes]
        if f"combined{suffix}" not in f:
            return
        starts[minutes] = f["target"] - steps
        for into, name in ((combined, "combined"), (arx, "arx")):
            into[steps] = np.full(n, np.nan)
            into[steps][starts[minutes]] = f[f"{name}{suffix}"]
        ahead[steps] = _ahead_change(result, starts[minutes], steps, suffix)
    out = correction.correct_series(combined, result.measured, result.x, result.time, result.dt,
                                    arx, ahead=ahead)
    for minutes, steps in reach.items():
        result.horizons[minutes][f"corrected{suffix}"] = out[steps][starts[minutes]]


def _ahead_change(result: ReplayResult, starts: np.ndarray, steps: int,
                  suffix: str) -> dict[str, np.ndarray]:
    """correction.ahead_change of each start's drivers (the measured weather, or the outlook's
    block for ``_outlook``), on the series' grid (NaN where no forecast starts)."""
    n = len(result.measured)
    if suffix and result.ahead is not None:
        x, rows = result.ahead.x, result.ahead.rows[np.searchsorted(result.ahead.starts, starts)]
    else:
        x, rows = result.x, starts
    out = {}
    for key, v in correction.ahead_change(x, rows, steps).items():
        out[key] = np.full(n, np.nan)
        out[key][starts] = v
    return out

"""Drivers over a forecast horizon from a weather outlook, for many start times at once.

A forecast of T_in[t + h] from t steps the model with the drivers at t, t + 1, …, t + h - 1 (and
a step may read the next row too). With the weather that was later measured (model skill) these
are the series' own rows. With an outlook every start has its own future: the rows are laid out
in blocks ``[now, now + 1, …, now + H]``, one block per start, so that ``Model.forecast`` and the
ARX baseline run on them unchanged (block b starts at row b (H + 1)).

Derived drivers (sky temperature, outside convection, vapour pressures, vent areas) are made by
the model layer's ``prepare_drivers`` from the outlook's columns, once per lead time k (the
k-step-ahead outlooks of consecutive starts form a regular time series, times t + k dt). The
cloud fraction is not read again from the outlook's radiation: it is held at the start's value
(what the estimator's tracker carries, gateway/model/sky.py) over the horizon, because that is
all the live gateway knows when it forecasts one block (``live_block``, which the service calls:
one derivation for replay and live).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.estimate.outlook import Outlook, forecast_drivers
from gateway.greenhouse import Greenhouse
from gateway.model import solar
from gateway.model.drivers import prepare_drivers
from gateway.series import Series


@dataclass
class HorizonDrivers:
    """Driver blocks: ``x`` flat arrays of ``len(starts) * (horizon + 1)`` rows; ``rows`` the
    row of each block's "now"; ``starts`` the series index of each block's "now"."""

    x: dict[str, np.ndarray]
    rows: np.ndarray
    starts: np.ndarray
    horizon: int
    outlook: str


def outlook_drivers(outlook: Outlook, x: Mapping[str, np.ndarray], kit_columns: Sequence[str],
                    time: np.ndarray, dt: float, gh: Greenhouse, starts: np.ndarray,
                    horizon: int) -> HorizonDrivers:
    """Blocks for ``starts`` over ``horizon`` steps: row 0 of each block is ``x`` at the start
    (what was measured and derived), rows 1 … horizon the outlook made from the kit columns
    ``kit_columns`` of ``x`` up to the start."""
    n = len(time)
    starts = np.asarray(starts, dtype=int)
    history = {c: np.asarray(x[c], dtype=float) for c in kit_columns if c in x}
    every = np.arange(n)
    ahead = forecast_drivers(outlook, history, time, every, horizon, dt)  # (n, H) per column
    blocks = {name: np.full((len(starts), horizon + 1), np.nan) for name in x}
    for name in x:
        blocks[name][:, 0] = np.asarray(x[name], dtype=float)[starts]
    step = np.timedelta64(int(round(dt)), "s")
    held = np.asarray(x["cloud"], dtype=float) if "cloud" in x else None  # each start's cloud
    for k in range(1, horizon + 1):
        cols = {c: v[:, k - 1] for c, v in ahead.items()}
        xk = prepare_drivers(Series(time + k * step, dt, cols), gh, cloud=held)
        for name in x:
            if name in xk:
                blocks[name][:, k] = np.asarray(xk[name], dtype=float)[starts]
    rows = np.arange(len(starts)) * (horizon + 1)
    flat = {name: b.ravel() for name, b in blocks.items()}
    return HorizonDrivers(flat, rows, starts, horizon, getattr(outlook, "name", type(outlook).__name__))


INSIDE_READINGS = ("t_in", "rh_in", "i_in", "t_soil", "p_w_in")
"""What the kit measures inside the house, and what is derived from it (``p_w_in``, III.4): the
house's response, not its weather. A forecast "with the weather later measured" reads these
at its start only: read at later rows they would hand it the future it forecasts (the Almería
transpiration's p_w,in carries T_in: at saturation p_w,in = p_ws(T_in))."""


def measured_weather_blocks(x: Mapping[str, np.ndarray], starts: np.ndarray,
                            horizon: int) -> HorizonDrivers:
    """Blocks for ``starts`` over ``horizon`` steps with the weather (and the grower's vents and
    crop) as later measured and derived, row by row, and the inside readings
    (``INSIDE_READINGS``) held at each start: the drivers of a model-skill forecast."""
    n = len(next(iter(x.values())))
    starts = np.asarray(starts, dtype=int)
    idx = np.minimum(starts[:, None] + np.arange(horizon + 1)[None, :], n - 1)
    held = np.repeat(starts[:, None], horizon + 1, axis=1)
    flat = {name: np.asarray(v, dtype=float)[held if name in INSIDE_READINGS else idx].ravel()
            for name, v in x.items()}
    rows = np.arange(len(starts)) * (horizon + 1)
    return HorizonDrivers(flat, rows, starts, horizon, "measured")


def live_block(outlook: Outlook, history: Mapping[str, np.ndarray], time: np.ndarray,
               horizon: int, dt: float, gh: Greenhouse, cloud: float) -> dict[str, np.ndarray]:
    """The drivers of the one forecast the live gateway makes now (the last row of ``history``):
    rows ``[now, now + 1, …, now + horizon - 1]``, row 0 the latest readings, the others the
    outlook's, derived as ``outlook_drivers`` derives a block's rows: with the cloud fraction
    ``cloud`` [-] (the estimator's at now) held over the horizon. The outlook reads ``i_glob``
    as replay's does, through ``solar.measured_global`` (``outlook_drivers`` is given the
    prepared drivers): a negative pyranometer offset counts as 0."""
    if "i_glob" in history:
        history = {**history, "i_glob": solar.measured_global(history["i_glob"])}
    ahead = outlook.drivers(history, time, horizon, dt)
    cols = {c: np.concatenate([np.asarray(history[c], float)[-1:], ahead[c][: horizon - 1]])
            for c in history}
    grid = time[-1] + np.arange(horizon) * np.timedelta64(int(round(dt)), "s")
    held = np.full(horizon, cloud) if np.isfinite(cloud) else None
    return prepare_drivers(Series(grid, dt, cols), gh, cloud=held)

"""Causal weather outlooks: the drivers a live forecast uses over its horizon.

A live gateway does not know the coming weather, so a forecast of T_in[t + h] made at t needs the
outside drivers over (t, t + h] from what was measured up to t. An outlook turns the history of
kit columns (oldest first, the last row being "now") into those columns for the next ``horizon``
steps. Every published forecast names the outlook it used (``Outlook.name``).

Columns the outlook does not forecast (inside humidity, vent openings, soil temperature, LAI)
are held at their latest finite value: they are the grower's or the crop's, not the weather's.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

import numpy as np

from gateway.estimate.clear_sky_trend import ClearSkyTrend, forward_fill
from gateway.greenhouse import Greenhouse


class Outlook(Protocol):
    """What the live gateway and ``replay`` call to get drivers over a forecast horizon."""

    name: str
    """Short identity published with each forecast, e.g. ``hold-latest``."""

    def drivers(
        self, history: Mapping[str, np.ndarray], time: np.ndarray, horizon: int, dt: float
    ) -> dict[str, np.ndarray]:
        """Kit columns for the steps now + 1 … now + ``horizon`` (arrays of length ``horizon``).

        ``history``: kit columns (docs/data-format.md names) up to and including now, all of
        the same length as ``time`` (datetime64[s], UTC, a regular grid of ``dt`` seconds).
        Missing values are NaN. The result has every column of ``history``; a column that cannot
        be forecast (no finite value at all) is NaN.
        """
        ...


def latest_finite(values: np.ndarray) -> float:
    """The last finite value of ``values`` (NaN when there is none)."""
    v = np.asarray(values, dtype=float)
    ok = np.flatnonzero(np.isfinite(v))
    return float(v[ok[-1]]) if ok.size else float("nan")


class HoldLatest:
    """Every column held at its latest finite value over the horizon (the naive outlook)."""

    name = "hold-latest"

    def drivers(
        self, history: Mapping[str, np.ndarray], time: np.ndarray, horizon: int, dt: float
    ) -> dict[str, np.ndarray]:
        if horizon < 0:
            raise ValueError(f"horizon must be >= 0, got {horizon}")
        return {k: np.full(horizon, latest_finite(v)) for k, v in history.items()}

    def drivers_at(self, columns: Mapping[str, np.ndarray], time: np.ndarray, starts: np.ndarray,
                   horizon: int, dt: float) -> dict[str, np.ndarray]:
        """``drivers`` for many starts at once: (N, horizon) arrays (see ``forecast_drivers``)."""
        starts = np.asarray(starts, dtype=int)
        return {k: np.repeat(forward_fill(np.asarray(v, float))[starts][:, None], horizon, axis=1)
                for k, v in columns.items()}


OUTLOOKS: dict[str, Callable[[Greenhouse], Outlook]] = {
    "hold-latest": lambda gh: HoldLatest(),
    ClearSkyTrend.name: ClearSkyTrend.for_greenhouse,
}
"""Outlooks by name (what a live gateway's configuration selects), each built for a greenhouse
(``clear-sky-trend`` needs its ``[site]``)."""


def default_outlook(gh: Greenhouse) -> str:
    """The outlook used when none is named: ``clear-sky-trend`` for a greenhouse with a
    ``[site]`` (it needs the sun's position), else ``hold-latest``. Side by side on the same
    replays it is better at 60 min and level at 30 (docs/online-estimator.md, "Which outlook
    live")."""
    return "clear-sky-trend" if gh.site is not None else "hold-latest"


def make_outlook(name: str, gh: Greenhouse) -> Outlook:
    """The outlook called ``name`` for greenhouse ``gh``; a clear error for an unknown name."""
    if name not in OUTLOOKS:
        raise ValueError(f"unknown weather outlook {name!r} (known: {', '.join(OUTLOOKS)})")
    return OUTLOOKS[name](gh)


def forecast_drivers(outlook: Outlook, columns: Mapping[str, np.ndarray], time: np.ndarray,
                     starts: np.ndarray, horizon: int, dt: float) -> dict[str, np.ndarray]:
    """What ``outlook`` gives for the steps start + 1 … start + horizon of every start: arrays
    (N, horizon) per column, from ``columns`` (a whole series on ``time``) read up to each start.

    Outlooks with a ``drivers_at`` method serve all starts in one call; any other
    :class:`Outlook` is called once per start on the history up to it.
    """
    batch = getattr(outlook, "drivers_at", None)
    if batch is not None:
        return batch(columns, time, starts, horizon, dt)
    starts = np.asarray(starts, dtype=int)
    out = {k: np.full((len(starts), horizon), np.nan) for k in columns}
    for row, s in enumerate(starts):
        got = outlook.drivers({k: np.asarray(v)[: s + 1] for k, v in columns.items()},
                              time[: s + 1], horizon, dt)
        for k in out:
            out[k][row] = got.get(k, np.nan)
    return out

"""Causal weather outlooks: the drivers a live forecast uses over its horizon.

A live gateway does not know the coming weather, so a forecast of T_in[t + h] made at t needs the
outside drivers over (t, t + h] from what was measured up to t. An outlook turns the history of
kit columns (oldest first, the last row being "now") into those columns for the next ``horizon``
steps. Every published forecast names the outlook it used (``Outlook.name``).

Columns the outlook does not forecast (inside humidity, vent openings, soil temperature, LAI)
are held at their latest finite value: they are the grower's or the crop's, not the weather's.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np


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


OUTLOOKS: dict[str, str] = {
    "hold-latest": "gateway.estimate.outlook:HoldLatest",
}
"""Outlooks the gateway config can name (``outlook = "..."``): name → ``module:class``. A new
outlook adds one line here (imported only when chosen, so no import cycle). The class is built
without arguments and its ``name`` must be the key."""


def make_outlook(name: str) -> Outlook:
    """The outlook registered as ``name`` (ValueError naming the known ones otherwise)."""
    import importlib

    target = OUTLOOKS.get(name)
    if target is None:
        raise ValueError(f"unknown weather outlook {name!r} (known: {', '.join(sorted(OUTLOOKS))})")
    module, _, attr = target.partition(":")
    outlook = getattr(importlib.import_module(module), attr)()
    if outlook.name != name:
        raise ValueError(f"outlook {target} calls itself {outlook.name!r}, registered as {name!r}")
    return outlook

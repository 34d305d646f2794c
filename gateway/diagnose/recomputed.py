"""Drivers the structured base recomputes per candidate (structure.Structured).

Two drivers depend on fitted base parameters, so the terms cannot read them from the series:
the sky temperature when the night sky level is fitted (night_sky.py, ``c_sky_night``), and
the inside vapour pressure behind an electronic offset of the temperature reading (the RH
refers to the true air, drivers.py, III.4). This module holds the view of the drivers with
those recomputed at a step (:func:`inputs`) and their precomputation for every step of every
free-run window at once (:func:`windows`, used by ``Structured.shoot``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from gateway.diagnose.night_sky import LEVEL, NightSky
from gateway.model import psychrometrics as psy
from gateway.model.terms import Index, SensorTerm

if TYPE_CHECKING:
    from gateway.diagnose.structure import Modulation


class Same:
    """Indexes to the same value whatever the index (one step's recomputed driver)."""

    def __init__(self, value: np.ndarray) -> None:
        self.value = value

    def __getitem__(self, t: Index) -> np.ndarray:
        return self.value


class Override(Mapping):
    """The drivers with some entries replaced."""

    def __init__(self, base: Mapping, overrides: dict) -> None:
        self.base, self.overrides = base, overrides

    def __getitem__(self, key: str):
        return self.overrides[key] if key in self.overrides else self.base[key]

    def __iter__(self):
        return iter(self.base)

    def __len__(self) -> int:
        return len(self.base)

    def __contains__(self, key: object) -> bool:
        return key in self.base


def electronic(sensors: Sequence[SensorTerm]) -> list[SensorTerm]:
    """The sensor terms that offset the temperature reading only (``electronic``)."""
    return [sn for sn in sensors if getattr(sn, "electronic", False)]


def vapour_in(sensors: Sequence[SensorTerm], p, x, t: Index) -> np.ndarray:
    """Inside vapour pressure from the reading corrected by the electronic offsets (III.4)."""
    off: np.ndarray | float = 0.0
    for sn in electronic(sensors):
        off = off + sn.offset(p, x, t)
    return psy.vapour_pressure(x["t_in"][t] - off, x["rh_in"][t])


def inputs(night_sky: NightSky | None, sensors: Sequence[SensorTerm], p, x, t: Index,
           given: Mapping[str, np.ndarray] | None = None):
    """The drivers as the terms should see them at ``t``: when a sensor term is an
    electronic offset of the temperature reading only (``electronic``), the inside vapour
    pressure computed from that reading and the RH (drivers.py, III.4) is recomputed
    from the corrected temperature; with a fitted night sky (night_sky.py), the sky
    temperature is the one of the fitted level. ``given``: those of them the caller
    already computed at ``t`` (``p_w_in``, ``t_sky``)."""
    given = given or {}
    overrides = {}
    if night_sky is not None:
        sky = given["t_sky"] if "t_sky" in given else night_sky.t_sky(p, x, t)
        overrides["t_sky"] = Same(sky)
    if electronic(sensors) and "rh_in" in x:
        pw = given["p_w_in"] if "p_w_in" in given else vapour_in(sensors, p, x, t)
        overrides["p_w_in"] = Same(pw)
    return Override(x, overrides) if overrides else x


def windows(night_sky: NightSky | None, sensors: Sequence[SensorTerm],
            modulations: Sequence[Modulation], p, x, starts: np.ndarray,
            horizon: int) -> dict[str, np.ndarray]:
    """The drivers :func:`inputs` recomputes per candidate (the fitted night sky's
    temperature, the vapour pressure behind electronic offsets) at steps 0..H-1 of every
    window: (P·N, H) each, rows ordered as ``shoot``'s (candidate-major). Computed once per
    call, not once per step, and once per distinct value of the parameters they read (a τ
    scan's candidates share them): the inputs are gathered per window (N, H), not per
    row; no modulation changes these parameters."""
    t = starts[:, None] + np.arange(horizon)[None, :]  # (N, H)
    out = {}
    if night_sky is not None:
        out["t_sky"] = per_distinct(modulations, p, [LEVEL.name], horizon,
                                    lambda q: night_sky.t_sky(q, x, t))
    if electronic(sensors) and "rh_in" in x:
        names = [q.name for sn in electronic(sensors) for q in sn.parameters]
        out["p_w_in"] = per_distinct(modulations, p, names, horizon,
                                     lambda q: vapour_in(sensors, q, x, t))
    return out


def check_unmodulated(modulations: Sequence[Modulation], names: Sequence[str]) -> None:
    """Raise ValueError when a modulation changes one of the parameters ``names``: the
    drivers read from them are computed once per run, from the unmodulated values."""
    for m in modulations:
        for nm in names:
            if nm in m.targets:
                raise ValueError(f"modulation {m.name!r} changes the parameter {nm!r}, which the "
                                 "drivers computed once per run read unmodulated (recomputed.py)")


def per_distinct(modulations: Sequence[Modulation], p, names: list[str], horizon: int,
                 f: Callable[[dict[str, np.ndarray]], np.ndarray]) -> np.ndarray:
    """``f`` of the parameters ``names`` (P, 1) evaluated once per distinct row: ``f``
    takes them as (U, 1, 1) and gives (U, N, H); returned as (P·N, H)."""
    check_unmodulated(modulations, names)
    cols = np.broadcast_arrays(*[p[nm][:, 0] for nm in names])  # a shared one is (1,)
    rows, which = np.unique(np.column_stack(cols), axis=0,
                            return_inverse=True)
    got = f({nm: rows[:, j, None, None] for j, nm in enumerate(names)})  # (U, N, H)
    return got[which.ravel()].reshape(-1, horizon)

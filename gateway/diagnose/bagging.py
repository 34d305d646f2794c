"""A bagged judge (issue 10, rule bq; docs/effects.md, "A bagged base"): opt-in
(``diagnose(..., bags=K)``), off by default.

Bag b (b = 0 … K−1) draws the calibration part's whole days (days since the first row) with
replacement, as many draws as days (numpy ``default_rng(b)``), and calibrates its own base with
``base.calibrate_base`` exactly as the diagnosis does (same seed, bounds, iterations, structure
choice), every set of shooting windows cut to those starting on drawn days, each repeated as
often as its day was drawn (``resample``; Breiman 1996, Machine Learning 24, 123–140). Each bag
carries its own search state on the diagnosis's context and held-out folds; every held-out
prediction the judge and the report see is the mean over the bags (``mean_pred``), while the
diagnosis's own state (main's base) still ranks, fits all data, gives the starts and ΔBIC and
reports the findings (search.py).

This module holds the bootstrap and the bags' state updates; the search's steps
(search.try_effect, reference, keep) run per bag state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gateway.diagnose.base import Progress, calibrate_base
from gateway.diagnose.effects import Effect
from gateway.diagnose.structure import Structured
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model

__all__ = ["DAY_S", "BagTry", "adopt", "bases", "calibration_days", "day_counts",
           "day_resample", "mean_pred"]

DAY_S = 86400.0
"""One day [s]: the bootstrap's unit."""


def day_counts(n_days: int, seed: int) -> np.ndarray:
    """How often each of ``n_days`` days was drawn: ``n_days`` draws with replacement
    (numpy ``default_rng(seed)``)."""
    draws = np.random.default_rng(seed).integers(0, n_days, n_days)
    return np.bincount(draws, minlength=n_days)


def day_resample(counts: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
    """Window starts (rows on a grid of ``dt`` [s]) → those on drawn days, each repeated as often
    as its day was drawn (calibrate_base's ``resample``)."""
    def pick(starts: np.ndarray) -> np.ndarray:
        day = (np.asarray(starts) * dt // DAY_S).astype(int)
        return np.repeat(starts, counts[day]).astype(int)
    return pick


def calibration_days(split: int, dt: float) -> int:
    """Days (a part day counts) in the calibration rows [0, ``split``) on a grid of ``dt`` [s]."""
    return int(np.ceil(split * dt / DAY_S - 1e-9))


def bases(base: Model, gh: Greenhouse, x: dict, dt: float, split: int, horizon: int, seed: int,
          bags: int, say: Progress) -> list[tuple[Structured, np.ndarray]]:
    """The ``bags`` bags' calibrated bases (model, parameters), bag b on day draw
    ``day_counts(days, b)`` (module docstring); ``seed`` is the calibration's own (the
    diagnosis's)."""
    n_days = calibration_days(split, dt)
    out = []
    for b in range(bags):
        say(f"bag {b + 1} of {bags}: calibrating its base on resampled days")
        m_b, th_b, _ = calibrate_base(base, gh, x, dt, split, horizon, seed, say,
                                      day_resample(day_counts(n_days, b), dt))
        out.append((m_b, th_b))
    return out


def mean_pred(preds: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Per key, the mean of the bags' held-out predictions (one prediction: itself)."""
    if len(preds) == 1:
        return preds[0]
    return {k: np.mean([p[k] for p in preds], axis=0) for k in preds[0]}


@dataclass(frozen=True)
class BagTry:
    """A candidate on one bag's state (search.try_effect): the bag's model so far with the
    effect composed on, its parameters per fold (fitted from the bag's fold parameters) and its
    cross-fitted held-out prediction."""

    model: Structured
    thetas: list[np.ndarray]
    pred: dict


def adopt(bag: Any, e: Effect, t: BagTry) -> None:
    """A kept candidate into a bag's state (search.State): its bag fits become the bag's model
    so far and held-out prediction. The bag is never fitted on all data (main's fit is the
    finding's), so its ``theta_all`` stays its base's."""
    bag.effects.append(e)
    bag.model, bag.thetas = t.model, t.thetas
    bag.current_pred = t.pred

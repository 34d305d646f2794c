"""Calibration costs: MSE of one-step-ahead or free-run prediction over one or more windows.

A cost takes only the free parameters, shape (P, k_free), and returns (P,): the fixed ones are
filled in from a base vector, so the same model description serves any subset (the radiation
stage fits c_tsw alone; the diagnosis fits a new term's parameters with the rest).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model.model import Model
from gateway.model.terms import SUNLIT

MODES = ("one_step", "free_run")


def slice_drivers(x: Mapping[str, np.ndarray], start: int, stop: int) -> dict[str, np.ndarray]:
    return {k: v[start:stop] for k, v in x.items()}


@dataclass
class Objective:
    """MSE (III.39, III.47 divided by N) of a model output against its measurement."""

    model: Model
    x: Mapping[str, np.ndarray]
    gh: Greenhouse
    dt: float
    free: np.ndarray  # indices into the model's parameter vector
    base: np.ndarray  # full parameter vector (k,) supplying the fixed values
    windows: Sequence[tuple[int, int]]
    mode: str = "one_step"
    output: str = "t_in"  # or "i_in" for the radiation sub-model

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        self._parts = [slice_drivers(self.x, a, b) for a, b in self.windows if b - a >= 2]
        if not self._parts:
            raise ValueError("no calibration window with at least two samples")

    def full(self, theta_free: np.ndarray) -> np.ndarray:
        theta_free = np.atleast_2d(theta_free)
        theta = np.repeat(self.base[None, :], theta_free.shape[0], axis=0)
        theta[:, self.free] = theta_free
        return theta

    def residuals(self, theta_free: np.ndarray) -> list[np.ndarray]:
        """Prediction minus measurement per window, each (P, T_w), NaN where not comparable."""
        theta = self.full(theta_free)
        out = []
        for x in self._parts:
            if self.output == "i_in":
                assert self.model.radiation is not None
                j = self.model.index(self.model.radiation.parameter.name)
                pred = self.model.radiation.predict(theta[:, j : j + 1], x)
                meas = np.where(SUNLIT(x), x["i_in"], np.nan)
            elif self.mode == "one_step":
                pred = self.model.one_step(theta, x, self.gh, self.dt)
                meas = x["t_in"]
            else:
                pred = self.model.free_run(theta, x, self.gh, self.dt)
                meas = x["t_in"]
            out.append(pred - meas[None, :])
        return out

    def __call__(self, theta_free: np.ndarray) -> np.ndarray:
        total = 0.0
        count = 0
        for r in self.residuals(theta_free):
            ok = np.isfinite(r[0])  # missing measurements are the same for every candidate
            total = total + np.sum(np.where(ok[None, :], r, 0.0) ** 2, axis=1)
            count += int(ok.sum())
        cost = total / max(count, 1)
        return np.where(np.isfinite(cost), cost, np.inf)

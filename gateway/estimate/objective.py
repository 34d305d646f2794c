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
        self._fast = None
        if self.mode == "one_step" and self.output == "t_in" and not self.model.sensors:
            self._fast = [_LinearOneStep(self.model, x, self.gh, self.dt, self.free, self.base)
                          for x in self._parts]

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
        if self._fast is not None:
            theta = self.full(theta_free)
            sse = sum(f.sse(theta) for f in self._fast)
            count = sum(f.count for f in self._fast)
            cost = sse / max(count, 1)
            return np.where(np.isfinite(cost), cost, np.inf)
        total = 0.0
        count = 0
        for r in self.residuals(theta_free):
            ok = np.isfinite(r[0])  # missing measurements are the same for every candidate
            total = total + np.sum(np.where(ok[None, :], r, 0.0) ** 2, axis=1)
            count += int(ok.sum())
        cost = total / max(count, 1)
        return np.where(np.isfinite(cost), cost, np.inf)


class _LinearOneStep:
    """The one-step-ahead squared error of a population, fast.

    In one-step mode the state is the measurement, so for a term that is linear in its own
    parameters (``FluxTerm.linear_in_parameters``) the coefficients are
    ``(g, s) = sum_j theta_j (g_j, s_j)`` with (g_j, s_j) fixed by the data: they are computed
    once here by evaluating the term with unit parameters, and a whole population then costs
    two matrix products plus the exponential step. Terms that are not linear (or whose
    ``uses`` parameters are being fitted) are evaluated as usual. The result equals
    ``Model.one_step`` (tests/test_objective.py).
    """

    def __init__(self, model, x, gh, dt, free, base) -> None:
        self.model, self.x, self.dt = model, x, dt
        self.c = model.capacity(gh)
        meas = x["t_in"]
        self.state = meas[None, :-1]
        self.target = meas[1:]
        self.valid = np.isfinite(self.target)  # refined below with the inputs' gaps
        n = len(meas) - 1
        t = slice(0, n)
        names = model.names
        free_names = {names[j] for j in free}
        base_p = {k: np.full((1, 1), v) for k, v in zip(names, base, strict=True)}
        self.g0 = np.zeros(n)
        self.s0 = np.zeros(n)
        cols, rows_g, rows_s = [], [], []
        self.other = []
        for term in model.terms:
            if not term.linear_in_parameters or free_names & set(term.uses):
                self.other.append(term)
                continue
            own = [q.name for q in term.parameters]
            for name in own:
                p = dict(base_p)
                for o in own:
                    p[o] = np.full((1, 1), 1.0 if o == name else 0.0)
                g, s = term.coefficients(p, x, self.state, t)
                g = np.broadcast_to(np.asarray(g, dtype=float), (1, n))[0]
                s = np.broadcast_to(np.asarray(s, dtype=float), (1, n))[0]
                if name in free_names:
                    cols.append(names.index(name))
                    rows_g.append(g)
                    rows_s.append(s)
                else:
                    self.g0 = self.g0 + base_p[name][0, 0] * g
                    self.s0 = self.s0 + base_p[name][0, 0] * s
        self.cols = np.array(cols, dtype=int)
        self.a_g = np.array(rows_g).reshape(len(cols), n)
        self.a_s = np.array(rows_s).reshape(len(cols), n)
        # Gaps in the inputs or the previous state give NaN for every candidate alike: the
        # comparable samples are those where the base parameters give a finite error.
        self.valid = np.isfinite(self._errors(np.asarray(base, float)[None, :], 0, n))[0]
        self.count = int(self.valid.sum())

    def _errors(self, theta: np.ndarray, a: int, b: int) -> np.ndarray:
        """Prediction minus measurement (P, b - a) for rows a..b of the one-step targets."""
        lin = theta[:, self.cols]
        g = self.g0[a:b] + lin @ self.a_g[:, a:b]
        s = self.s0[a:b] + lin @ self.a_s[:, a:b]
        state = self.state[:, a:b]
        if self.other:
            p = self.model.columns(theta)
            for term in self.other:
                dg, ds = term.coefficients(p, self.x, state, slice(a, b))
                g = g + dg
                s = s + ds
        k = self.dt / self.c
        z = np.maximum(s * k, 1e-12)
        return state + (g - s * state) * k * (-np.expm1(-z) / z) - self.target[a:b]

    def sse(self, theta: np.ndarray) -> np.ndarray:
        """Sum of squared one-step errors (P,) over the comparable samples."""
        total = np.zeros(theta.shape[0])
        block = max(16, 16384 // theta.shape[0])
        n = len(self.target)
        for a in range(0, n, block):
            b = min(a + block, n)
            err = np.where(self.valid[a:b], self._errors(theta, a, b), 0.0)
            total += np.einsum("ij,ij->i", err, err)
        return total

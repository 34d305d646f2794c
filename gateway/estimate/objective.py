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
from gateway.model import step as stepping
from gateway.model.model import Model
from gateway.model.terms import SUNLIT, const

MODES = ("one_step", "free_run")
_HALF = const(0.5)


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
        self._parts = [self.model.prepare(slice_drivers(self.x, a, b))  # FluxTerm.derive, once
                       for a, b in self.windows if b - a >= 2]
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

    In one-step mode the state at the start of every step is the measurement, so for a term
    that is linear in its own parameters (``FluxTerm.linear_in_parameters``) the flux and slope
    at the start, ``(F, k) = sum_j theta_j (F_j, k_j)``, are fixed by the data: they are computed
    once here by evaluating the term with unit parameters, and a whole population then costs
    matrix products plus the exponential step. The same holds at the step's end for terms whose
    coefficients do not depend on the state (``FluxTerm.state_dependent``); the others are
    evaluated there at the population's midpoint states, as are terms that are not linear (or
    whose ``uses`` parameters are being fitted) at both ends. The step is
    ``gateway.model.step``'s, so the result equals ``Model.one_step`` (tests/test_objective.py).
    """

    def __init__(self, model, x, gh, dt, free, base) -> None:
        self.model, self.x, self.dt = model, x, dt
        self.c = model.capacity(gh)
        # C, Δ and Δ/2 as 0-d operands (terms.const): the same operations, no conversion per block
        self._c, self._dt, self._half = const(self.c), const(dt), const(0.5 * dt)
        self.scheme = model.integration
        meas = x["t_in"]
        self.size = len(meas)
        self.state = meas[None, :-1]
        self.target = meas[1:]
        n = len(meas) - 1
        t = slice(0, n)
        t1 = stepping.next_index(t, self.size)
        free_names = {model.names[j] for j in free}
        self.base_p = {k: np.full((1, 1), v) for k, v in zip(model.names, base, strict=True)}
        # F = g - s T and slope k at the measured state, at the start and (for the terms that
        # do not read the state, or all of them when not re-linearised) at the end
        start = _Sums(model, free, n)
        end = _Sums(model, free, n)
        self.other, self.end_other = [], []
        relin = self.scheme.relinearise
        for term in model.terms:
            if not term.linear_in_parameters or free_names & set(term.uses):
                self.other.append(term)
                self.end_other.append(term)
                continue
            start.add(term, self.base_p, free_names, self._unit(term, x, self.state, t, relin))
            if term.state_dependent and relin:
                self.end_other.append(term)  # evaluated at the midpoint state
            else:
                end.add(term, self.base_p, free_names, self._unit(term, x, self.state, t1, relin))
        self.start, self.end = start.close(1.0 / self.c), end.close(1.0 / self.c)
        # where the drivers at t + 1 are missing the step holds those at t (step.end_rates);
        # known from the data alone, so blocks without such a sample skip the check
        r1, k1 = model.rates(self.base_p, x, self.state, t1, self.c)
        self.end_missing = ~np.isfinite(np.broadcast_to(r1 + k1, (1, n))[0])
        self._missing = _running_count(self.end_missing)  # blocks without one skip the check
        # Gaps in the inputs or the previous state give NaN for every candidate alike: the
        # comparable samples are those where the base parameters give a finite error.
        self.valid = np.isfinite(self._errors(np.asarray(base, float)[None, :], 0, n))[0]
        self.count = int(self.valid.sum())
        self._invalid = _running_count(~self.valid)  # blocks without one skip the mask

    @staticmethod
    def _unit(term, x, state, t, relin):
        """A function of the parameter dict giving the term's flux F = g - s T and slope k at
        the (measured) start state and time ``t``."""

        def rows(p):
            if relin:
                g, s, k = term.linearised(p, x, state, t)
            else:
                g, s = term.coefficients(p, x, state, t)
                k = s
            return g - s * state, k

        return rows

    def _operands(self, theta: np.ndarray) -> tuple:
        """What every block of one population's evaluation reads from ``theta``: the parameter
        columns (``Model.columns``, None when no term is evaluated per candidate) and the free
        parameters of the start and end sums (``_Sums.at``), taken once per population."""
        p = self.model.columns(theta) if self.end_other else None
        return p, self.start.rows(theta), self.end.rows(theta)

    def _errors(self, theta: np.ndarray, a: int, b: int, operands: tuple | None = None) -> np.ndarray:
        """Prediction minus measurement (P, b - a) for rows a..b of the one-step targets;
        ``operands``: ``_operands(theta)`` when the caller holds them."""
        p, lin0, lin1 = self._operands(theta) if operands is None else operands
        r0, lam0 = self.start.at(lin0, a, b)  # rates [K s-1] and slopes [s-1]
        state = self.state[:, a:b]
        t = slice(a, b)
        relin = self.scheme.relinearise
        c = self._c
        for term in self.other:
            f, k = self._unit(term, self.x, state, t, relin)(p)
            r0, lam0 = r0 + f / c, lam0 + k / c
        if self.scheme.hold == "zero_order":
            return stepping.advance(state, r0, lam0, self.dt) - self.target[a:b]

        def rates(st, tt):  # the terms that read the state, at the midpoint state
            f = k = None  # the first term's own (g - s T, k): no addition to a zero
            for term in self.end_other:
                if relin:
                    g, s, kk = term.linearised(p, self.x, st, tt)
                else:
                    g, s = term.coefficients(p, self.x, st, tt)
                    kk = s
                ff = g - s * st
                f, k = (ff, kk) if f is None else (f + ff, k + kk)
            if f is None:
                return 0.0, 0.0
            return f / c, k / c

        fixed = self.end.at(lin1, a, b)  # the others' rate at the start state, and slope
        t1 = stepping.next_index(t, self.size)
        r1, lam1 = stepping.end_rates(rates, state, r0, lam0, t1, self.dt, relin, fixed=fixed,
                                      check=bool(self._missing[b] > self._missing[a]),
                                      half=self._half)
        pred = stepping.advance(state, r0, _HALF * (lam0 + lam1), self._dt, r1)
        return pred - self.target[a:b]

    def sse(self, theta: np.ndarray) -> np.ndarray:
        """Sum of squared one-step errors (P,) over the comparable samples."""
        total = np.zeros(theta.shape[0])
        block = max(16, stepping.BLOCK_ELEMENTS // theta.shape[0])
        n = len(self.target)
        operands = self._operands(theta)
        bad = self._invalid
        for a in range(0, n, block):
            b = min(a + block, n)
            err = self._errors(theta, a, b, operands)
            if bad[b] > bad[a]:  # a block without such samples keeps every error as is
                err = np.where(self.valid[a:b], err, 0.0)
            total += np.einsum("ij,ij->i", err, err)
        return total


class _Sums:
    """Two rows (u, v) of a sum of terms linear in their parameters, precomputed: a fixed part
    (the parameters not being fitted, at their base values) plus one row per free parameter,
    so that a population costs ``fixed + theta_free @ rows``."""

    def __init__(self, model: Model, free: np.ndarray, n: int) -> None:
        self.names = model.names
        self.u0, self.v0 = np.zeros(n), np.zeros(n)
        self.cols: list[int] = []
        self.u: list[np.ndarray] = []
        self.v: list[np.ndarray] = []
        self.n = n

    def add(self, term, base_p, free_names, rows) -> None:
        own = [q.name for q in term.parameters]
        for name in own:
            p = dict(base_p)
            for o in own:
                p[o] = np.full((1, 1), 1.0 if o == name else 0.0)
            u, v = (np.broadcast_to(np.asarray(r, dtype=float), (1, self.n))[0] for r in rows(p))
            if name in free_names:
                self.cols.append(self.names.index(name))
                self.u.append(u)
                self.v.append(v)
            else:
                self.u0 = self.u0 + base_p[name][0, 0] * u
                self.v0 = self.v0 + base_p[name][0, 0] * v

    def close(self, scale: float = 1.0) -> _Sums:
        """Freeze the rows, multiplied by ``scale`` (1/C: fluxes to rates)."""
        self.idx = np.array(self.cols, dtype=int)
        self.a_u = scale * np.array(self.u).reshape(len(self.cols), self.n)
        self.a_v = scale * np.array(self.v).reshape(len(self.cols), self.n)
        self.u0, self.v0 = scale * self.u0, scale * self.v0
        # no fixed part (every parameter of these terms is free): ``at`` adds nothing, which
        # gives the same numbers as adding the zeros (x + 0 = x; only a zero's sign could
        # differ, and a rate's or slope's zero is never divided by)
        self.zero = not (self.u0.any() or self.v0.any())
        return self

    def rows(self, theta: np.ndarray) -> np.ndarray:
        """The free parameters of these terms (P, k) from a population ``theta`` (P, K)."""
        return theta[:, self.idx]

    def at(self, lin: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) at rows a..b for the free parameters ``lin`` (``rows``)."""
        u, v = lin @ self.a_u[:, a:b], lin @ self.a_v[:, a:b]
        if self.zero:
            return u, v
        return self.u0[a:b] + u, self.v0[a:b] + v


def _running_count(flags: np.ndarray) -> np.ndarray:
    """c[i] = number of true ``flags`` before i (length n + 1): rows a..b hold one iff
    c[b] > c[a]."""
    return np.concatenate([[0], np.cumsum(flags, dtype=np.int64)])

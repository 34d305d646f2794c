"""Fitting for the diagnosis: multiple-shooting free runs, τ scans and joint refits.

The cost is the mean squared error of *free runs* of ``horizon`` steps started from the
measured state at many times (multiple shooting): close to the free-run error the diagnosis is
judged on, robust to drift and gaps, and vectorised over candidates × start times, so one
Python iteration per step of the horizon serves the whole population.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gateway.diagnose.effects import INDEX, Effect
from gateway.estimate.swarm import ALMERIA_OFFLINE, bat
from gateway.greenhouse import Greenhouse
from gateway.model.drivers import prepare_drivers
from gateway.model.model import Model
from gateway.series import Series

HORIZON_S = 3 * 3600.0
"""Length of one shooting window [s]: long enough for the slow heat balance to show."""


def drivers(series: Series, gh: Greenhouse) -> dict[str, np.ndarray]:
    """Model drivers plus the absolute sample index the effect terms' τ refers to."""
    x = prepare_drivers(series, gh)
    x[INDEX] = np.arange(len(series), dtype=float)
    return x


def window_starts(segments: list[tuple[int, int]], horizon: int) -> np.ndarray:
    """Start indices of back-to-back windows of ``horizon`` steps inside each [a, b)."""
    out = [np.arange(a, b - horizon, horizon) for a, b in segments if b - a > horizon]
    return np.concatenate(out) if out else np.zeros(0, dtype=int)


@dataclass
class Shooting:
    """Free runs of ``horizon`` steps from ``starts`` for a population of parameter sets."""

    model: Model
    x: dict[str, np.ndarray]
    gh: Greenhouse
    dt: float
    starts: np.ndarray
    horizon: int
    target: np.ndarray = field(init=False)  # (N, H) measured T_in at steps 1..H

    def __post_init__(self) -> None:
        t = self.starts[:, None] + np.arange(1, self.horizon + 1)[None, :]
        self.target = self.x["t_in"][t]

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """Readings predicted at steps 1..H of every window: (P, N, H)."""
        theta = np.atleast_2d(theta)
        n_p, n = theta.shape[0], len(self.starts)
        m = self.model
        p = m.columns(np.repeat(theta, n, axis=0))  # row r = candidate r // N, window r % N
        t0 = np.tile(self.starts, n_p)[:, None]
        c = m.capacity(self.gh)
        state = self.x["t_in"][t0]
        if m.sensors:
            state = state - m.sensor_offset(p, self.x, t0)
        out = np.empty((n_p * n, self.horizon))
        for k in range(self.horizon):
            state = m.step(p, self.x, state, t0 + k, c, self.dt)
            obs = state + m.sensor_offset(p, self.x, t0 + k + 1) if m.sensors else state
            out[:, k] = obs[:, 0]
        return out.reshape(n_p, n, self.horizon)

    def residual(self, theta: np.ndarray) -> np.ndarray:
        """Prediction minus measurement (P, N, H), NaN where not comparable."""
        return self.predict(theta) - self.target[None]

    def sse(self, theta: np.ndarray) -> tuple[np.ndarray, int]:
        """Sum of squared residuals per candidate (P,) and the number of compared pairs."""
        r = self.residual(theta)
        # pairs every candidate can be compared on (input gaps are the same for all of them);
        # a candidate whose run diverges where others do not gets NaN, i.e. an infinite cost
        ok = np.isfinite(self.target) & np.isfinite(r).any(axis=0)
        r = np.where(ok[None], r, 0.0).reshape(len(r), -1)
        return np.sum(r * r, axis=1), int(ok.sum())

    def mse(self, theta: np.ndarray) -> np.ndarray:
        s, n = self.sse(theta)
        return np.where(np.isfinite(s), s / max(n, 1), np.inf)


def fit_swarm(
    shoot: Shooting,
    theta0: np.ndarray,
    free: list[int],
    lower: np.ndarray,
    upper: np.ndarray,
    iterations: int,
    seed: int,
) -> np.ndarray:
    """RSBA (§IV.2.2.1.A settings, fewer iterations) on the shooting MSE; ``theta0`` seeds
    bat 0, so the result is never worse than the start on this cost."""
    free_idx = np.asarray(free)

    def cost(u: np.ndarray) -> np.ndarray:
        theta = np.repeat(theta0[None, :], len(u), axis=0)
        theta[:, free_idx] = u
        return shoot.mse(theta)

    from dataclasses import replace

    st = replace(ALMERIA_OFFLINE, iterations=iterations)
    res = bat(cost, lower[free_idx], upper[free_idx], st, "rsba", np.random.default_rng(seed),
              x0=theta0[free_idx])
    theta = theta0.copy()
    theta[free_idx] = res.best
    return theta


def radiation_fit(model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
                  span: tuple[int, int]) -> np.ndarray:
    """c_tsw by least squares of measured i_in on i_glob (III.35) over ``span``, when measured."""
    if model.radiation is None or "i_in" not in x:
        return theta
    a, b = span
    i_out, i_in = x["i_glob"][a:b], x["i_in"][a:b]
    ok = np.isfinite(i_out) & np.isfinite(i_in) & (i_out > 5.0)
    if ok.sum() < 10:
        return theta
    j = model.index(model.radiation.parameter.name)
    p = model.radiation.parameter
    theta = theta.copy()
    theta[j] = float(np.clip(np.sum(i_in[ok] * i_out[ok]) / np.sum(i_out[ok] ** 2), p.lower, p.upper))
    return theta


@dataclass
class Scan:
    """Result of a τ scan for one effect: best τ, amplitude and SSE per τ."""

    effect: Effect
    taus: np.ndarray
    amps: np.ndarray
    sse: np.ndarray
    n: int

    @property
    def best(self) -> int:
        return int(np.argmin(self.sse))


def scan_tau(
    shoot: Shooting, theta: np.ndarray, effect: Effect, taus: np.ndarray, sse0: float
) -> Scan:
    """Amplitude and SSE for every candidate start τ at once (rows of one population).

    Two secant (Gauss–Newton) steps on the amplitude from its neutral value, per τ, with the
    model's other parameters held: the linearisation is one extra run, the secant corrects
    for the nonlinearity of e.g. a capacity factor.
    """
    m = shoot.model
    ja, jt = m.index(effect.amp_name), m.index(effect.tau_name)
    rows = np.repeat(theta[None, :], len(taus), axis=0)
    rows[:, jt] = taus
    rows[:, ja] = effect.neutral
    r0 = shoot.residual(theta[None, :])[0]
    ok = np.isfinite(r0)
    r0 = np.where(ok, r0, 0.0)
    a0 = effect.neutral
    delta = 0.02 * (effect.upper - effect.lower)
    best_a = np.full(len(taus), a0)
    best_sse = np.full(len(taus), sse0)
    a_prev = np.full(len(taus), a0 + delta)
    for _ in range(2):
        rows[:, ja] = a_prev
        r = shoot.residual(rows)
        r = np.where(ok[None], r, 0.0)
        jac = (r - r0[None]).reshape(len(taus), -1) / (a_prev - a0)[:, None]
        den = np.sum(jac * jac, axis=1)
        step = -np.sum(jac * r0.reshape(1, -1), axis=1) / np.where(den > 0, den, np.inf)
        a_new = np.clip(a0 + step, effect.lower, effect.upper)
        rows[:, ja] = a_new
        sse_new, _ = shoot.sse(rows)
        better = np.isfinite(sse_new) & (sse_new < best_sse)
        best_a[better], best_sse[better] = a_new[better], sse_new[better]
        # next secant from the new point (fall back to a small step where nothing moved)
        a_prev = np.where(np.abs(a_new - a0) > 1e-9 * (effect.upper - effect.lower), a_new, a0 + delta)
    return Scan(effect, taus, best_a, best_sse, int(ok.sum()))

"""Fitting for the diagnosis: multiple-shooting free runs, τ scans and joint refits.

The cost is the mean squared error of *free runs* of ``horizon`` steps started from the
measured state at many times (multiple shooting): close to the free-run error the diagnosis is
judged on, robust to drift and gaps, and vectorised over candidates × start times, so one
Python iteration per step of the horizon serves the whole population.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gateway.diagnose.effects import Effect
from gateway.diagnose.night_sky import sky_drivers
from gateway.diagnose.structure import INDEX, Structured
from gateway.estimate.swarm import ALMERIA_OFFLINE, bat
from gateway.greenhouse import Greenhouse
from gateway.model.drivers import prepare_drivers
from gateway.model.model import Model
from gateway.series import Series

HORIZON_S = 6 * 3600.0
"""Length of one shooting window [s]: long enough for the slow heat balance to show."""


def drivers(series: Series, gh: Greenhouse) -> dict[str, np.ndarray]:
    """Model drivers plus the clock the effect terms' τ refers to [s since the first sample]."""
    x = prepare_drivers(series, gh)
    x.update(sky_drivers(series, gh, x))
    x[INDEX] = (series.time - series.time[0]).astype("timedelta64[s]").astype(float)
    return x


def coarsen(series: Series, k: int) -> Series:
    """Every k-th reading of T_in (the state), block means of the inputs over the k samples
    that follow it (the zero-order hold the exponential step assumes). Fits run on this grid:
    the heat balance's time scales (tens of minutes to days) are resolved at 5 minutes, and a
    free run of 5-minute steps costs a fifth of one of 1-minute steps."""
    if k <= 1:
        return series
    n = len(series) // k * k
    cols = {}
    with np.errstate(all="ignore"):
        for name, v in series.columns.items():
            v = np.asarray(v, dtype=float)
            if name == "t_in":
                cols[name] = v[:n:k].copy()
                continue
            blocks = v[:n].reshape(-1, k)
            ok = np.isfinite(blocks)
            cnt = ok.sum(axis=1)
            tot = np.where(ok, blocks, 0.0).sum(axis=1)
            cols[name] = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    return Series(time=series.time[:n:k], step=series.step * k, columns=cols,
                  source=series.source, notices=list(series.notices))


def window_starts(segments: list[tuple[int, int]], horizon: int, skip: int = 0) -> np.ndarray:
    """Start indices of back-to-back windows of ``horizon`` steps inside each [a, b), none
    before sample ``skip`` (the store observer's start-up)."""
    out = []
    for a, b in segments:
        a = max(a, skip)
        if b - a - 1 < horizon:  # a window needs its start plus ``horizon`` later samples
            continue
        starts = np.arange(a, b - horizon, horizon)
        if starts[-1] + horizon < b - 1:  # one more window, overlapping, ends at the segment's end
            starts = np.append(starts, b - 1 - horizon)
        out.append(starts)
    return np.concatenate(out).astype(int) if out else np.zeros(0, dtype=int)


@dataclass
class Shooting:
    """Free runs of ``horizon`` steps from ``starts`` for a population of parameter sets."""

    model: Structured
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
        return self.model.shoot(theta, self.x, self.gh, self.dt, self.starts, self.horizon)

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

    st = replace(ALMERIA_OFFLINE, iterations=iterations)
    res = bat(cost, lower[free_idx], upper[free_idx], st, "rsba", np.random.default_rng(seed),
              x0=theta0[free_idx])
    theta = theta0.copy()
    theta[free_idx] = res.best
    return theta


def fit_lm(shoot: Shooting, theta0: np.ndarray, free: list[int], lower: np.ndarray,
           upper: np.ndarray, iterations: int = 15) -> np.ndarray:
    """Box-bounded Levenberg–Marquardt on the multiple-shooting residuals.

    Works in box-normalised coordinates like the swarm. Each iteration is two population
    calls: the forward-difference Jacobian (the k+1 parameter sets as one population) and the
    trial steps for a ladder of damping values (again one population). Polishes a swarm result:
    the swarm explores, this converges.
    """
    free_idx = np.asarray(free, dtype=int)
    lo, hi = lower[free_idx], upper[free_idx]
    width = np.where(hi > lo, hi - lo, 1.0)
    theta = theta0.copy()
    r0 = shoot.residual(theta[None])[0]
    ok = np.isfinite(r0).reshape(-1)

    def flat(r: np.ndarray) -> np.ndarray:
        f = r.reshape(len(r), -1)[:, ok]
        return np.where(np.isfinite(f), f, 1e3)  # a diverged run costs a lot, not NaN

    f0 = flat(r0[None])[0]
    cost0 = float(f0 @ f0)
    mus = np.array([1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])
    k = len(free_idx)
    for _ in range(iterations):
        u = (theta[free_idx] - lo) / width
        h = np.where(u > 0.5, -1e-4, 1e-4)
        rows = np.repeat(theta[None, :], k + 1, axis=0)
        rows[np.arange(1, k + 1), free_idx] += h * width
        f = flat(shoot.residual(rows))
        jac = (f[1:] - f[0][None, :]) / h[:, None]  # (k, M)
        a = jac @ jac.T
        g = jac @ f[0]
        d = np.diag(a) + 1e-12
        trials = np.repeat(theta[None, :], len(mus), axis=0)
        for i, mu in enumerate(mus):
            try:
                step = -np.linalg.solve(a + mu * np.diag(d), g)
            except np.linalg.LinAlgError:
                step = np.zeros(k)
            trials[i, free_idx] = lo + np.clip(u + step, 0.0, 1.0) * width
        ft = flat(shoot.residual(trials))
        costs = np.sum(ft * ft, axis=1)
        j = int(np.argmin(costs))
        if not costs[j] < cost0 * (1.0 - 1e-6):
            break
        theta, cost0 = trials[j], float(costs[j])
    return theta


def radiation_fit(model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
                  span: tuple[int, int]) -> np.ndarray:
    """c_tsw by least squares of measured i_in on i_glob (III.35) over ``span``, when measured
    (``RadiationSubmodel.fit``, the model layer's one fit)."""
    if model.radiation is None:
        return theta
    fit = model.radiation.fit(x, span)
    if fit is None:
        return theta
    theta = theta.copy()
    theta[model.index(model.radiation.parameter.name)] = fit.value
    return theta


@dataclass
class Scan:
    """Result of a τ scan for one effect: best τ, amplitude and SSE per τ."""

    effect: Effect
    taus: np.ndarray
    amps: np.ndarray
    sse: np.ndarray
    n: int
    pick: int | None = None
    """Chosen index when it is not simply the lowest score (see ``latest_of_best``)."""
    score: np.ndarray | None = None
    """What the start is chosen on: the SSE, or the SSE times exp(ΔBIC_2 / n_e) when a second
    output speaks (ΔBIC_2 its ΔBIC at each τ, n_e the temperature's effective samples: the
    sum of both ΔBIC, bic.py, ordered as an SSE); None: the SSE."""

    @property
    def scores(self) -> np.ndarray:
        return self.sse if self.score is None else self.score

    @property
    def best(self) -> int:
        return int(np.argmin(self.scores)) if self.pick is None else self.pick

    def latest_of_best(self, rel: float) -> Scan:
        """The latest τ of the contiguous run of τ (in time order) around the best whose score
        is within ``rel`` × the best score of it. Start times between two pieces of fit data (a
        held-out block, a night for a solar effect) fit equally well; the latest one says "no
        change until the data shows it", and keeps a judged block free of a guessed effect."""
        order = np.argsort(self.taus)
        score = self.scores[order]
        i = int(np.argmin(score))
        limit = score[i] * (1.0 + rel)
        while i + 1 < len(score) and score[i + 1] <= limit:
            i += 1
        return replace(self, pick=int(order[i]))


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

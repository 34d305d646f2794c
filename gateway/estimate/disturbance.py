"""A disturbance state on top of the grey-box model: Kalman filter and forecast (issue 10).

The standard grey-box practice (Kristensen, Madsen & Jørgensen 2004, "Parameter estimation in
stochastic grey-box models", Automatica 40, 225-237; the offset-free disturbance model of
Pannocchia & Rawlings 2003, AIChE J. 49, 426-437): the air balance the model integrates is
augmented with what it lacks, a slowly varying heating rate b [K s-1] (stored sun given back,
a heat source, a wrong coefficient), and the reading with the sensor's noise:

    T[t+1] = f_θ(T[t], t) + Δ b[t] + w_T,    w_T ~ N(0, q_T Δ / Δ_REF)
    b[t+1] = ρ b[t] + w_b,                   ρ = exp(-Δ / τ_b),  var w_b = σ_b² (1 - ρ²)
    y[t]   = T[t] + o(t) + v,                v ~ N(0, σ_v²)

``f_θ`` is the model's own exact step (``Model.stepper``) with the parameters the online
estimator had in force at t, linearised around the reading for the covariance (an extended
Kalman filter); ``o`` the model's sensor terms. The filter gives, at every t and from readings
up to t only, a filtered state T̂ (the DHT22's noise taken out of the start) and b̂. A forecast
starts from T̂ and adds the disturbance decaying as ρ^k over the horizon, so far ahead it returns
to the grey box; the drivers are the measured weather or an outlook's, as for ``Model.forecast``.

Nothing in the model or the estimator changes: any model and any set of terms get the same
filter, and its settings (``DisturbanceSettings``) are physical scales chosen once on the
reference simulator and the two-node house (never on the held-out generator) and not tuned per
dataset. docs/online-estimator.md, "Forecasts", has the figures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model.model import Model

DT_REF = 300.0
"""[s] the step the scales below are stated for (the kit's 5-minute rows)."""


@dataclass(frozen=True)
class DisturbanceSettings:
    """Noise scales of the augmented model (all per ``DT_REF``; other steps scale them)."""

    sigma_v: float = math.hypot(0.08, 0.1 / math.sqrt(12.0))
    """[K] reading noise: DHT22 repeatability 0.08 K and its 0.1 K resolution (datasheet)."""
    q_t: float = 0.01
    """[K²] white model error of T per DT_REF (0.1 K standard deviation in 5 min)."""
    tau_b: float = -DT_REF / math.log(0.9)
    """[s] correlation time of the disturbance (~47 min: ρ = 0.9 per 5 minutes)."""
    sigma_b: float = math.sqrt(1e-3 / (1.0 - 0.81)) / DT_REF
    """[K s-1] stationary standard deviation of b (~0.9 K h-1)."""

    def per_step(self, dt: float) -> tuple[float, float, float, float]:
        """(ρ, q_T [K²], q_b [(K s-1)²], r [K²]) for a step of ``dt`` seconds."""
        rho = math.exp(-dt / self.tau_b)
        return rho, self.q_t * dt / DT_REF, self.sigma_b**2 * (1.0 - rho * rho), self.sigma_v**2


@dataclass
class FilterState:
    """The filter at one instant: estimates and their covariance [[p_tt, p_tb], [p_tb, p_bb]]."""

    t: float
    b: float
    p_tt: float
    p_tb: float
    p_bb: float

    def predict(self, f0: float, a: float, t_lin: float, dt: float,
                s: DisturbanceSettings) -> None:
        """Time update with the step linearised at ``t_lin``: f(T) ≈ f0 + a (T - t_lin)."""
        rho, q_t, q_b, _ = s.per_step(dt)
        self.t, self.b = f0 + a * (self.t - t_lin) + dt * self.b, rho * self.b
        # P <- F P F' + Q with F = [[a, dt], [0, rho]]
        tt = a * a * self.p_tt + 2 * a * dt * self.p_tb + dt * dt * self.p_bb + q_t
        tb = rho * (a * self.p_tb + dt * self.p_bb)
        self.p_tt, self.p_tb, self.p_bb = tt, tb, rho * rho * self.p_bb + q_b

    def correct(self, y: float, s: DisturbanceSettings) -> None:
        """Measurement update with the true-state reading ``y`` (sensor offset removed)."""
        r = s.sigma_v**2
        k_t, k_b = self.p_tt / (self.p_tt + r), self.p_tb / (self.p_tt + r)
        e = y - self.t
        self.t, self.b = self.t + k_t * e, self.b + k_b * e
        self.p_tt, self.p_tb, self.p_bb = ((1 - k_t) * self.p_tt, (1 - k_t) * self.p_tb,
                                           self.p_bb - k_b * self.p_tb)

    @classmethod
    def start(cls, y: float, s: DisturbanceSettings) -> FilterState:
        """From a first reading: T at the reading, b at its prior (0 ± σ_b)."""
        return cls(y, 0.0, s.sigma_v**2, 0.0, s.sigma_b**2)


@dataclass
class FilterResult:
    """The filter over a series (length T): ``t_hat`` [°C] true-state estimate at t and
    ``b_hat`` [K s-1] disturbance at t, from readings up to t only (NaN before the start)."""

    t_hat: np.ndarray
    b_hat: np.ndarray
    settings: DisturbanceSettings


def linearised_steps(model: Model, theta: np.ndarray, x: Mapping[str, np.ndarray],
                     gh: Greenhouse, dt: float, around: np.ndarray,
                     delta: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(f0, a) per t: the model's step from the true state ``around[t]`` with ``theta[t]`` and
    its slope ∂f/∂T by a finite difference of ``delta`` K (vectorised over t)."""
    n = len(around)
    p = model.columns(theta)
    t = np.arange(n)[:, None]
    step = model.stepper(p, x, model.capacity(gh), dt)
    lo = np.asarray(around, dtype=float)[:, None]
    both = step(np.hstack([lo, lo + delta]), t)
    return both[:, 0], (both[:, 1] - both[:, 0]) / delta


def filter_series(model: Model, theta: np.ndarray, x: Mapping[str, np.ndarray], gh: Greenhouse,
                  dt: float, settings: DisturbanceSettings | None = None) -> FilterResult:
    """Run the filter over a replayed series: ``theta`` (T, k) the parameters in force at each t
    (after the estimator's update at t), ``x`` the drivers it saw (with ``t_in`` the readings).

    A step that cannot be made (missing drivers or parameters) restarts the filter at the next
    reading, keeping b̂; a missing reading is a time update only (dead reckoning)."""
    s = settings or DisturbanceSettings()
    y_read = np.asarray(x["t_in"], dtype=float)
    n = len(y_read)
    ok_theta = np.all(np.isfinite(theta), axis=1)
    t_hat, b_hat = np.full(n, np.nan), np.full(n, np.nan)
    if not ok_theta.any():
        return FilterResult(t_hat, b_hat, s)
    # rows without parameters are never stepped; any finite row keeps the vectorised call clean
    th = np.where(ok_theta[:, None], theta, theta[np.argmax(ok_theta)][None, :])
    offset: np.ndarray | float = 0.0
    if model.sensors:
        offset = np.asarray(model.sensor_offset(model.columns(th), x, np.arange(n)[:, None]),
                            dtype=float).reshape(-1)
    y = y_read - offset  # readings of the true state
    lin = _forward_fill(y)
    lin = np.where(np.isfinite(lin), lin, 0.0)  # where the step is linearised
    f0, a = linearised_steps(model, th, x, gh, dt, lin)
    state: FilterState | None = None
    for t in range(n):
        if state is not None and t > 0:
            if ok_theta[t - 1] and math.isfinite(f0[t - 1]) and math.isfinite(a[t - 1]):
                state.predict(f0[t - 1], a[t - 1], lin[t - 1], dt, s)
            elif math.isfinite(y[t]):  # cannot step: restart at the reading, keep b
                state = FilterState(y[t], state.b, s.sigma_v**2, 0.0, state.p_bb)
        if math.isfinite(y[t]):
            if state is None:
                state = FilterState.start(y[t], s)
            else:
                state.correct(y[t], s)
        if state is not None and math.isfinite(state.t):
            t_hat[t], b_hat[t] = state.t, state.b
        elif state is not None:
            state = None
    return FilterResult(t_hat, b_hat, s)


def _forward_fill(v: np.ndarray) -> np.ndarray:
    ok = np.isfinite(v)
    idx = np.where(ok, np.arange(len(v)), 0)
    np.maximum.accumulate(idx, out=idx)
    out = v[idx]
    out[: np.argmax(ok) if ok.any() else len(v)] = np.nan
    return out


def forecast(model: Model, theta_rows: np.ndarray, x: Mapping[str, np.ndarray], gh: Greenhouse,
             dt: float, rows: np.ndarray, horizon: int, t_hat: np.ndarray, b_hat: np.ndarray,
             settings: DisturbanceSettings | None = None) -> np.ndarray:
    """Readings at row + ``horizon`` from the filtered state ``t_hat`` (N,) and disturbance
    ``b_hat`` (N,) of each start, with ``theta_rows`` (N, k) and the drivers of ``x`` from row
    ``rows`` on (the series' own rows, or an outlook's blocks): the model's steps plus
    Δ ρ^k b̂ (vectorised over the starts, as ``Model.forecast``)."""
    return forecast_each(model, theta_rows, x, gh, dt, rows, [horizon], t_hat, b_hat,
                         settings)[horizon]


def forecast_each(model: Model, theta_rows: np.ndarray, x: Mapping[str, np.ndarray],
                  gh: Greenhouse, dt: float, rows: np.ndarray, horizons: Sequence[int],
                  t_hat: np.ndarray, b_hat: np.ndarray,
                  settings: DisturbanceSettings | None = None) -> dict[int, np.ndarray]:
    """{h: ``forecast`` of horizon h} for each of ``horizons``: one run to the longest, read at
    each on the way (the shorter runs are its first steps: the same numbers)."""
    s = settings or DisturbanceSettings()
    rho = s.per_step(dt)[0]
    p = model.columns(theta_rows)
    t = np.asarray(rows, dtype=int)[:, None]
    state = np.asarray(t_hat, dtype=float)[:, None]
    b = np.asarray(b_hat, dtype=float)[:, None]
    step = model.stepper(p, x, model.capacity(gh), dt)
    out, done = {}, 0  # done: the steps taken
    for h in sorted(set(horizons)):
        for k in range(done, h):
            state = step(state, t + k) + dt * b * rho**k
        done = max(done, h)
        out[h] = model.reading(p, x, state, t + h)[:, 0]
    return out


class LiveFilter:
    """The same filter one sample at a time, for the live gateway (gateway/service/pipeline.py):
    ``update`` after the estimator's update at t, ``estimate`` for the forecasts made at t.
    Fed a replay's rows and parameters it gives ``filter_series``'s figures."""

    def __init__(self, model: Model, gh: Greenhouse, dt: float,
                 settings: DisturbanceSettings | None = None) -> None:
        self.model, self.gh, self.dt = model, gh, dt
        self.settings = settings or DisturbanceSettings()
        self.state: FilterState | None = None
        self._prev: tuple[dict[str, float], np.ndarray, float] | None = None  # row, θ, lin

    def update(self, row: Mapping[str, float], theta: np.ndarray) -> None:
        """The drivers at t (the estimator's ``last_row``, ``t_in`` the reading) and the
        parameters in force after its update at t."""
        theta = np.asarray(theta, dtype=float)
        y = float(row.get("t_in", math.nan))
        if self.model.sensors and math.isfinite(y) and np.all(np.isfinite(theta)):
            x1 = {k: np.array([v]) for k, v in row.items()}
            p = self.model.columns(theta[None, :])
            y -= float(np.asarray(self.model.sensor_offset(p, x1, 0)).reshape(-1)[0])
        s = self.settings
        if self.state is not None and self._prev is not None:
            f0, a = self._step(*self._prev, row)
            if math.isfinite(f0) and math.isfinite(a):
                self.state.predict(f0, a, self._prev[2], self.dt, s)
            elif math.isfinite(y):  # cannot step: restart at the reading, keep b
                self.state = FilterState(y, self.state.b, s.sigma_v**2, 0.0, self.state.p_bb)
        if math.isfinite(y):
            if self.state is None:
                self.state = FilterState.start(y, s)
            else:
                self.state.correct(y, s)
        if self.state is not None and not math.isfinite(self.state.t):
            self.state = None
        lin = y if math.isfinite(y) else (self._prev[2] if self._prev is not None else 0.0)
        self._prev = (dict(row), theta, lin)

    def _step(self, row0: dict[str, float], theta: np.ndarray, lin: float,
              row1: Mapping[str, float]) -> tuple[float, float]:
        if not np.all(np.isfinite(theta)):
            return math.nan, math.nan
        x = {k: np.array([row0.get(k, math.nan), row1.get(k, math.nan)]) for k in row0}
        f0, a = linearised_steps(self.model, np.repeat(theta[None, :], 2, axis=0), x, self.gh,
                                 self.dt, np.array([lin, lin]))
        return float(f0[0]), float(a[0])

    def estimate(self) -> tuple[float, float] | None:
        """(T̂ [°C], b̂ [K s-1]) now, or None before the first reading."""
        return None if self.state is None else (self.state.t, self.state.b)

    def reset(self) -> None:
        """Forget everything (after a long gap in the data)."""
        self.state, self._prev = None, None

    def snapshot(self) -> dict:
        """JSON-ready state for an exact resume (``restore``)."""
        st = self.state
        prev = self._prev
        return {"state": None if st is None else [st.t, st.b, st.p_tt, st.p_tb, st.p_bb],
                "prev": None if prev is None else [prev[0], prev[1].tolist(), prev[2]]}

    def restore(self, snap: Mapping | None) -> None:
        """Continue from a ``snapshot`` (None: start afresh)."""
        self.reset()
        if not snap:
            return
        if snap.get("state") is not None:
            self.state = FilterState(*map(float, snap["state"]))
        if snap.get("prev") is not None:
            row, theta, lin = snap["prev"]
            self._prev = ({k: float(v) for k, v in row.items()}, np.asarray(theta, float), float(lin))

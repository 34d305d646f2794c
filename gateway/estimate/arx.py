"""The plain adaptive linear baseline: recursive least squares on a linear model of dT_in.

Every accuracy figure of the grey-box model stands beside this baseline (issue 10): a linear
model of the one-step change of the inside temperature on the same kit inputs,

    T_in[t+1] - T_in[t] = θ · φ[t],
    φ[t] = (I_glob, T_out - T_in, u (T_out - T_in), T_sky - T_in, 1)[t],

fitted by recursive least squares with exponential forgetting λ = 0.995 (Ljung 1999,
*System Identification*, §11.2, eq. 11.12; the same update as Åström & Wittenmark,
*Adaptive Control*, §2.2). Its settings are fixed here and never tuned per dataset: it is the
naive adaptive model a demanding user would try first. ``T_sky`` is the model layer's
(``prepare_drivers``), so the baseline and the grey-box model see the same sky.

The parameters in force at t (``ArxResult.theta[t]``) were fitted on the pairs up to
(φ[t-1], T_in[t] - T_in[t-1]) only: nothing after t is read, as in the live gateway.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

FORGETTING = 0.995
"""Forgetting factor λ [-] per sample (issue 10's baseline)."""
REGRESSORS = ("i_glob", "t_out - t_in", "wind (t_out - t_in)", "t_sky - t_in", "1")
"""Names of the regressors φ, in order."""
SCALE = np.array([1e-3, 1.0, 1.0, 1.0, 1.0])
"""Regressors are used in these units (I_glob in kW m-2) so that one initial covariance suits
all of them; ``ArxResult.theta`` is reported per the unscaled regressors."""
P0 = 100.0
"""Initial covariance P = P0 I (a diffuse start: the first samples set the parameters)."""
P_MAX = 1e4
"""Bound on the trace of P: without excitation (radiation at night, calm wind) forgetting grows
P by 1/λ per sample without end (covariance wind-up); the bound keeps the update finite. It
bounds P only while P stays symmetric positive semi-definite, which ``Rls.update`` keeps."""


def regressors(x: Mapping[str, np.ndarray], t_in: np.ndarray,
               t: int | np.ndarray | slice) -> np.ndarray:
    """φ (…, 5) at time index ``t`` for inside temperature ``t_in`` (broadcast against x[t])."""
    dt_out = x["t_out"][t] - t_in
    one = np.ones_like(dt_out)
    return np.stack([x["i_glob"][t] * one, dt_out, x["wind"][t] * dt_out,
                     x["t_sky"][t] - t_in, one], axis=-1)


@dataclass
class ArxResult:
    """The baseline run over a series (length T).

    ``theta`` (T, 5): parameters in force at t (per unscaled regressor; NaN before the first
    update); ``one_step`` (T,): prediction of T_in[t] made at t - 1 (NaN at 0); ``updates``:
    number of pairs used.
    """

    theta: np.ndarray
    one_step: np.ndarray
    updates: int

    def forecast(self, x: Mapping[str, np.ndarray], starts: np.ndarray, horizon: int,
                 rows: np.ndarray | None = None) -> np.ndarray:
        """T_in[start + horizon] from the measured T_in[start] with the parameters in force at
        each start and the drivers of ``x`` from row ``rows`` on (default: the starts; driver
        blocks of gateway/estimate/horizon.py have rows of their own), vectorised over starts;
        each step is ``forecast_step`` (the coefficient on T_in held in its physical range)."""
        return self.forecast_each(x, starts, [horizon], rows)[horizon]

    def forecast_each(self, x: Mapping[str, np.ndarray], starts: np.ndarray,
                      horizons: Sequence[int], rows: np.ndarray | None = None) -> dict[int, np.ndarray]:
        """{h: ``forecast`` of horizon h} for each of ``horizons``: one run to the longest, read
        at each on the way (the shorter runs are its first steps: the same numbers)."""
        starts = np.asarray(starts, dtype=int)
        rows = starts if rows is None else np.asarray(rows, dtype=int)
        theta = self.theta[starts]
        start = np.asarray(x["t_in"], dtype=float)[rows]
        state, out, done = start, {}, 0  # done: the steps taken
        for h in sorted(set(horizons)):
            for k in range(done, h):
                state = forecast_step(x, state, start, theta, rows + k)
            done = max(done, h)
            out[h] = state
        return out


def exchange(theta: np.ndarray, wind: np.ndarray) -> np.ndarray:
    """c = θ₂ + θ₃ u + θ₄: the step's coefficient on −T_in (the exchange with the outside air and
    the sky per step; the recursion's multiplier on T_in is 1 − c)."""
    return theta[..., 1] + theta[..., 2] * wind + theta[..., 3]


def forecast_step(x: Mapping[str, np.ndarray], state: np.ndarray, start: np.ndarray,
                  theta: np.ndarray, t: np.ndarray) -> np.ndarray:
    """One step of the forecast recursion from ``state`` with the drivers of row ``t``; ``start``
    is the measured T_in the forecast started from.

    The fitted step is kept at the start's temperature, where the fit has its data; how the step
    changes as the forecast moves away from it follows the coefficient on T_in clipped to the
    physical range, c* = min(max(c, 0), 1):

        T[k+1] = T[k] + θ · φ(T_start)[k] − c*[k] (T[k] − T_start),

    heat flows from warm to cold (c ≥ 0: a warmer inside gains less) and a step cannot overshoot
    its equilibrium (c ≤ 1). Where 0 ≤ c ≤ 1 this is the unguarded recursion T + θ · φ(T)
    exactly (θ · φ is linear in T with slope −c); outside, the unguarded one amplifies
    (1 − c > 1) or oscillates (1 − c < 0) and a 60-step forecast of poorly excited parameters
    runs away (docs/online-estimator.md, "The ARX baseline on 1-minute data"). The RLS fit is
    not touched, and the first step (the one-step prediction) is the unguarded one.
    """
    c = exchange(theta, x["wind"][t])
    clipped = np.clip(c, 0.0, 1.0)
    step = np.einsum("nj,nj->n", regressors(x, state, t), theta)
    return state + step + (c - clipped) * (state - start)


class Rls:
    """Recursive least squares with exponential forgetting on the scaled regressors (one pair at
    a time: ``fit`` over a series, the live gateway sample by sample)."""

    def __init__(self, forgetting: float = FORGETTING) -> None:
        self.lam = float(forgetting)
        self._reset()

    def _reset(self) -> None:
        """The initial state (no update yet)."""
        k = len(REGRESSORS)
        self.w = np.zeros(k)
        self.p = P0 * np.eye(k)
        self.updates = 0

    @property
    def theta(self) -> np.ndarray:
        """Parameters per unscaled regressor (NaN before the first update)."""
        return self.w * SCALE if self.updates else np.full(len(REGRESSORS), np.nan)

    def update(self, phi: np.ndarray, dy: float) -> None:
        """One pair: unscaled regressors φ[t] (``regressors``) and T_in[t + 1] − T_in[t]."""
        phi = np.asarray(phi, dtype=float) * SCALE
        if not (np.all(np.isfinite(phi)) and np.isfinite(dy)):
            return  # a pair with a missing value: the parameters are held
        pphi = self.p @ phi
        gain = pphi / (self.lam + phi @ pphi)
        self.w = self.w + gain * (dy - phi @ self.w)
        p = (self.p - np.outer(gain, pphi)) / self.lam
        # Keep P symmetric: in the conventional update the rounding error of P's antisymmetric
        # part is not damped, it grows by 1/λ per sample (Verhaegen 1989, Automatica 25(3),
        # 437-444). On 1-minute data (λ = 0.995 per sample: a 3.3-h memory, P's condition
        # number up to 4e6) it reached 2e-5 of ‖P‖, P turned indefinite after 3.3 days of the
        # 15-day replay, the gain then pushed θ away from the data and the forecasts ran to
        # 1e50 (tests/bench/arx_stability.py; docs/online-estimator.md, "The ARX baseline on
        # 1-minute data").
        self.p = 0.5 * (p + p.T)
        tr = np.trace(self.p)
        if tr > P_MAX:
            self.p *= P_MAX / tr
        self.updates += 1

    def snapshot(self) -> dict:
        return {"w": self.w.tolist(), "p": self.p.tolist(), "updates": self.updates}

    def restore(self, snap: Mapping) -> None:
        """Back to a saved state; a state whose P is not symmetric positive definite (saved by
        the conventional update, which could lose it) is dropped for a fresh start."""
        w, p = np.asarray(snap["w"], float), np.asarray(snap["p"], float)
        p = 0.5 * (p + p.T)
        finite = bool(np.all(np.isfinite(w)) and np.all(np.isfinite(p)))
        if not finite or np.linalg.eigvalsh(p)[0] < -1e-9 * abs(np.trace(p)):
            self._reset()
            return
        self.w, self.p = w, p
        self.updates = int(snap["updates"])


def fit(x: Mapping[str, np.ndarray], forgetting: float = FORGETTING) -> ArxResult:
    """Run RLS over the drivers ``x`` (``t_in``, ``t_out``, ``wind``, ``i_glob``, ``t_sky``).

    A pair with a missing value is skipped (the parameters are held); so is a prediction.
    """
    t_in = np.asarray(x["t_in"], dtype=float)
    n = len(t_in)
    phi_raw = regressors(x, t_in, slice(0, n))  # (T, 5)
    dy = np.full(n, np.nan)
    dy[:-1] = t_in[1:] - t_in[:-1]
    rls = Rls(forgetting)
    theta = np.full((n, len(REGRESSORS)), np.nan)
    for t in range(n):
        theta[t] = rls.theta  # in force at t: it used pairs up to t - 1 (set before the update)
        rls.update(phi_raw[t], dy[t])  # the pair (phi[t], T[t+1] - T[t]) is known from t + 1 on
    one_step = np.full(n, np.nan)
    one_step[1:] = t_in[:-1] + np.einsum("nj,nj->n", phi_raw[:-1], theta[:-1])
    return ArxResult(theta=theta, one_step=one_step, updates=rls.updates)

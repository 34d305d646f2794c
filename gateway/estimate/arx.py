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

from collections.abc import Mapping
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
P by 1/λ per sample without end (covariance wind-up); the bound keeps the update finite."""


def regressors(x: Mapping[str, np.ndarray], t_in: np.ndarray, t: np.ndarray | slice) -> np.ndarray:
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
        blocks of gateway/estimate/horizon.py have rows of their own), vectorised over starts."""
        starts = np.asarray(starts, dtype=int)
        rows = starts if rows is None else np.asarray(rows, dtype=int)
        theta = self.theta[starts]
        state = np.asarray(x["t_in"], dtype=float)[rows]
        for k in range(horizon):
            phi = regressors(x, state, rows + k)
            state = state + np.einsum("nj,nj->n", phi, theta)
        return state


def fit(x: Mapping[str, np.ndarray], forgetting: float = FORGETTING) -> ArxResult:
    """Run RLS over the drivers ``x`` (``t_in``, ``t_out``, ``wind``, ``i_glob``, ``t_sky``).

    A pair with a missing value is skipped (the parameters are held); so is a prediction.
    """
    t_in = np.asarray(x["t_in"], dtype=float)
    n = len(t_in)
    phi_all = regressors(x, t_in, slice(0, n)) * SCALE  # (T, 5)
    dy = np.full(n, np.nan)
    dy[:-1] = t_in[1:] - t_in[:-1]
    ok = np.all(np.isfinite(phi_all), axis=1) & np.isfinite(dy)
    k = phi_all.shape[1]
    w = np.zeros(k)
    p = P0 * np.eye(k)
    theta = np.full((n, k), np.nan)
    started = False
    updates = 0
    lam = float(forgetting)
    for t in range(n):
        if started:
            theta[t] = w
        if ok[t]:  # the pair (phi[t], T[t+1] - T[t]) is known from t + 1 on
            phi = phi_all[t]
            pphi = p @ phi
            gain = pphi / (lam + phi @ pphi)
            w = w + gain * (dy[t] - phi @ w)
            p = (p - np.outer(gain, pphi)) / lam
            tr = np.trace(p)
            if tr > P_MAX:
                p *= P_MAX / tr
            started = True
            updates += 1
    # theta[t] is in force at t: it used pairs up to t - 1 (set before the update at t).
    theta = theta * SCALE
    one_step = np.full(n, np.nan)
    phi_raw = regressors(x, t_in, slice(0, n))
    one_step[1:] = t_in[:-1] + np.einsum("nj,nj->n", phi_raw[:-1], theta[:-1])
    return ArxResult(theta=theta, one_step=one_step, updates=updates)

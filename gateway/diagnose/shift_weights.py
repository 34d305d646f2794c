"""Covariate-shift weights for the base calibration (issue 10, cw; rule /work/notes/cw-rule.txt).

The base's held-out day error follows how far a held-out day's weather lies from the
calibration days' (docs/effects.md, "The base's day-scale error against daily weather"): a
misspecified grey-box model fitted on one week's weather extrapolates badly to another's. The
textbook remedy is to weight the fit toward the test inputs' distribution (Shimodaira 2000,
J. Stat. Plan. Inference 90, 227-244; Sugiyama et al. 2007, JMLR 8, 985-1005):

    w = (p_H(z) / p_C(z))^λ,  λ = 0.5 (Shimodaira's flattening)

per shooting window, z = the window's mean T_out [°C], I_glob [W m-2], wind [m s-1] and VPD_out
[kPa], kit columns only. The density ratio comes from a logistic regression (standardised z, L2
with C = 1, intercept unpenalised) of held-out windows (rows >= s) against calibration windows
(rows < s): p_H / p_C = (n_C / n_H) · P(H|z) / P(C|z) (Bayes). The weights are clipped to
[0.2, 5] and then normalised to mean 1 over the windows of one fit. The diagnosis knows the
held-out part's weather when it calibrates; the held-out T_in and rh_in are never read here.
All settings are the rule's, fixed before any measurement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.diagnose.fit import window_starts
from gateway.model.psychrometrics import vapour_pressure_deficit

LAMBDA = 0.5
"""Flattening exponent of the density ratio (Shimodaira 2000)."""
C_L2 = 1.0
"""Inverse L2 strength of the logistic regression: penalty ||β||² / (2 C) on standardised z."""
CLIP = (0.2, 5.0)
"""Bounds of the flattened ratio before normalising to mean 1."""
NEWTON_STEPS = 50


def window_weather(x: dict[str, np.ndarray], starts: np.ndarray, horizon: int) -> np.ndarray:
    """z (N, 4): each window's mean T_out, I_glob, wind, VPD_out over the rows that drive its
    free run, [start, start + horizon); NaN where a column has no finite row in it."""
    vpd = vapour_pressure_deficit(x["t_out"], x["rh_out"]) if "rh_out" in x else np.full_like(
        x["t_out"], np.nan)
    cols = np.column_stack([x["t_out"], x["i_glob"], x["wind"], vpd])
    rows = starts[:, None] + np.arange(horizon)[None, :]
    with np.errstate(all="ignore"):
        z = np.nanmean(cols[rows], axis=1) if len(starts) else np.zeros((0, 4))
    return z


def logistic_l2(z: np.ndarray, y: np.ndarray, c: float = C_L2, steps: int = NEWTON_STEPS
                ) -> np.ndarray:
    """Coefficients [intercept, β] of P(y = 1 | z) = σ(b0 + z β), by Newton steps on the
    log-loss + ||β||² / (2 c) (the intercept unpenalised); ``z`` already standardised."""
    a = np.column_stack([np.ones(len(z)), z])
    pen = np.full(a.shape[1], 1.0 / c)
    pen[0] = 0.0
    beta = np.zeros(a.shape[1])
    for _ in range(steps):
        p = 1.0 / (1.0 + np.exp(-(a @ beta)))
        grad = a.T @ (p - y) + pen * beta
        hess = (a * (p * (1.0 - p))[:, None]).T @ a + np.diag(pen) + 1e-9 * np.eye(a.shape[1])
        step = np.linalg.solve(hess, grad)
        beta -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return beta


@dataclass(frozen=True)
class ShiftRatio:
    """The fitted density ratio p_H(z) / p_C(z) of one calibration (``fit_ratio``)."""

    mean: np.ndarray
    scale: np.ndarray
    beta: np.ndarray
    prior: float
    """n_C / n_H: the classifier's odds divided by the sample sizes' odds."""

    def standard(self, z: np.ndarray) -> np.ndarray:
        """z standardised, a missing value at the pooled mean (0)."""
        u = (z - self.mean) / self.scale
        return np.where(np.isfinite(u), u, 0.0)

    def ratio(self, z: np.ndarray) -> np.ndarray:
        """p_H / p_C at each row of z: (n_C / n_H) · P(H|z) / P(C|z) = (n_C / n_H) · e^η."""
        eta = self.beta[0] + self.standard(z) @ self.beta[1:]
        return self.prior * np.exp(eta)

    def weights(self, z: np.ndarray) -> np.ndarray:
        """(ratio^λ clipped to CLIP) / its mean over these windows (mean 1)."""
        w = np.clip(self.ratio(z) ** LAMBDA, *CLIP)
        return w / w.mean() if len(w) else w


def fit_ratio(x: dict[str, np.ndarray], s: int, horizon: int) -> ShiftRatio:
    """The logistic regression of the back-to-back windows of rows >= s (held-out) against
    those of rows < s (calibration), on their weather z; only kit weather columns are read."""
    n = len(x["t_out"])
    z_c = window_weather(x, window_starts([(0, s)], horizon), horizon)
    z_h = window_weather(x, window_starts([(s, n)], horizon), horizon)
    z = np.vstack([z_c, z_h])
    y = np.concatenate([np.zeros(len(z_c)), np.ones(len(z_h))])
    with np.errstate(all="ignore"):
        mean = np.nanmean(z, axis=0)
        sd = np.nanstd(z, axis=0)
    mean = np.where(np.isfinite(mean), mean, 0.0)
    scale = np.where(np.isfinite(sd) & (sd > 0), sd, 1.0)
    out = ShiftRatio(mean, scale, np.zeros(z.shape[1] + 1), len(z_c) / max(len(z_h), 1))
    if len(z_c) == 0 or len(z_h) == 0:
        return out
    beta = logistic_l2(out.standard(z), y)
    return ShiftRatio(mean, scale, beta, out.prior)


def shift_weights(ratio: ShiftRatio, x: dict[str, np.ndarray], starts: np.ndarray,
                  horizon: int) -> np.ndarray:
    """Per-window weights (N,) of the shooting windows ``starts``, mean 1 over them."""
    return ratio.weights(window_weather(x, starts, horizon))

"""The judge's one-sided tests of a held-out cut (docs/effects.md, "How the diagnosis
decides"): over 6-h pieces whose differences are autocorrelated (``paired_p``) and over whole
days taken as AR(1) across days (``day_p``, the shipped test: ``judge.DAY_TEST``)."""

from __future__ import annotations

import numpy as np

from gateway.diagnose.student_t import student_t_sf

DETREND_MIN_PIECES = 16
"""From this many pieces (4 days of 6 h) ``paired_p`` reads their autocorrelation about a line
in time, not about their mean."""
DAY_RHO = 0.5
"""Day-to-day correlation of the held-out error that ``day_p`` is built for (AR(1) across days;
not estimated per candidate: from 3 to 7 day means an estimate is noise, biased low)."""
MIN_DAYS = 3
"""Held-out days after a candidate's start that ``day_p`` needs: its pieces after the start must
fall on at least this many days (counted from the data's first row; a part day counts). With
fewer, under ``judge.DAY_TEST``, the candidate cannot be judged yet and its verdict says so."""


def paired_p(d: np.ndarray) -> float:
    """One-sided p-value of mean(d) > 0 for held-out pieces whose differences are
    autocorrelated (one weather spell spans several pieces): a Student t test on the effective
    number of pieces n (1 − r)/(1 + r), r the lag-1 autocorrelation of the pieces (AR(1)),
    clipped to [0, 0.9]. 1 with fewer than 4 pieces.

    With at least ``DETREND_MIN_PIECES`` pieces, r is estimated from the pieces' deviations
    from a straight line in time, with the small-sample correction (4 + 8r)/n: an effect whose
    gain grows in time (a drift) puts a trend in d, and a trend read as autocorrelation left a
    75 % cut over seven days at p = 0.1 (r at its 0.9 limit). With fewer pieces (the line costs
    too much of them) r is estimated about the mean with Kendall's correction (1 + 4r)/n. On
    AR(1) differences of mean zero (r 0 to 0.8, 16 to 28 pieces) the detrended test's size is
    at or below the mean-only one's; both are checked in tests/test_diagnose_judge.py. The
    variance of the mean is taken about the mean either way (a trend widens it: conservative).
    """
    n = len(d)
    if n < 4:
        return 1.0
    z = d - d.mean()
    ss = float(z @ z)
    if ss == 0.0:
        return 0.0 if d.mean() > 0 else 1.0
    if n >= DETREND_MIN_PIECES:
        t_c = np.arange(n) - 0.5 * (n - 1)
        w = z - (z @ t_c) / (t_c @ t_c) * t_c
        sw = float(w @ w)
        r = float(w[1:] @ w[:-1]) / sw if sw > 0 else 0.0
        r = r + (4.0 + 8.0 * r) / n
    else:
        r = float(z[1:] @ z[:-1]) / ss
        r = r + (1.0 + 4.0 * r) / n
    r = min(max(r, 0.0), 0.9)
    n_eff = n * (1.0 - r) / (1.0 + r)
    t = float(d.mean() / (np.std(d, ddof=1) / np.sqrt(n_eff)))
    return student_t_sf(t, max(n_eff - 1.0, 1.0))


def day_p(d: np.ndarray, day: np.ndarray, rho: float | None = None,
          weights: np.ndarray | None = None) -> float:
    """One-sided p-value of mean(d) > 0 with whole days as the units: the pieces' differences
    ``d`` averaged per ``day`` label (any correlation within a day is then inside one unit),
    and the day means taken as AR(1) across days with correlation ``rho`` (``DAY_RHO``).

    A Student t on the day means whose variance is matched to that correlation (R_ij =
    rho^|i-j|, M the centring matrix, K days): Var(mean) = sigma² 1'R1/K², and the sample sum
    of squares has E[z'z] = sigma² tr(MR), so sigma² is read as z'z / tr(MR); degrees of
    freedom tr(MR)²/tr(MRMR) (Satterthwaite). Exact in the first two moments on Gaussian day
    means of that correlation, conservative for less. 1 with fewer than ``MIN_DAYS`` days.

    ``weights`` (one per day label, sorted, ≥ 0; ``DAY_WEIGHTS``): the matched-filter form, the
    test of β > 0 in m = β w + e with e ~ AR(1) as above: t = w'm / √(σ² w'Rw), σ² = z'z/tr(PR)
    with z = Pm, P = I − ww'/w'w, df tr(PR)²/tr(PRPR). w = 1 is the form above (P = M); fewer
    than ``MIN_DAYS`` days with w > 0 give 1."""
    rho = DAY_RHO if rho is None else rho
    labels = np.unique(day)
    if len(labels) < MIN_DAYS:
        return 1.0
    m = np.array([d[day == k].mean() for k in labels])
    k = len(m)
    lag = np.abs(np.subtract.outer(labels, labels)).astype(float)  # gaps count as days
    R = rho**lag
    if weights is not None:
        return _weighted_day_p(m, np.asarray(weights, dtype=float), R)
    MR = R - R.mean(axis=0, keepdims=True)
    a = float(np.trace(MR))
    z = m - m.mean()
    ss = float(z @ z)
    if ss == 0.0:
        return 0.0 if m.mean() > 0 else 1.0
    var_mean = ss / a * float(R.sum()) / k**2
    df = a * a / float(np.sum(MR * MR.T))
    return student_t_sf(float(m.mean() / np.sqrt(var_mean)), max(df, 1.0))


def _weighted_day_p(m: np.ndarray, w: np.ndarray, R: np.ndarray) -> float:
    """``day_p``'s matched-filter form on the day means ``m`` with weights ``w`` and the
    declared day correlation matrix ``R``."""
    if np.count_nonzero(w > 0) < MIN_DAYS:
        return 1.0
    P = np.eye(len(w)) - np.outer(w, w) / float(w @ w)
    PR = P @ R
    a = float(np.trace(PR))
    z = P @ m
    ss, num = float(z @ z), float(w @ m)
    if ss == 0.0:
        return 0.0 if num > 0 else 1.0
    var = ss / a * float(w @ R @ w)
    df = a * a / float(np.sum(PR * PR.T))
    return student_t_sf(num / np.sqrt(var), max(df, 1.0))

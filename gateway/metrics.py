"""Goodness-of-fit criteria of thesis III.49–III.52, on the finite pairs only."""

from __future__ import annotations

import numpy as np


def metrics(measured: np.ndarray, predicted: np.ndarray) -> dict[str, float] | None:
    """MAE, RMSE, MaxAE, R² and EF of ``predicted`` against ``measured``; None if no pair.

    R² is the squared Pearson correlation: printed III.51 omits the square root in the
    denominator. EF is the Nash–Sutcliffe model efficiency (III.52). ``n`` counts the pairs.
    """
    m = np.asarray(measured, dtype=float)
    p = np.asarray(predicted, dtype=float)
    ok = np.isfinite(m) & np.isfinite(p)
    n = int(ok.sum())
    if n == 0:
        return None
    m, p = m[ok], p[ok]
    e = p - m
    dm = m - m.mean()
    dp = p - p.mean()
    sst = float(np.sum(dm * dm))
    denom = float(np.sqrt(sst * np.sum(dp * dp)))
    return {
        "mae": float(np.mean(np.abs(e))),
        "rmse": float(np.sqrt(np.mean(e * e))),
        "maxae": float(np.max(np.abs(e))),
        "r2": float((np.sum(dm * dp) / denom) ** 2) if denom > 0 else float("nan"),
        "ef": float(1.0 - np.sum(e * e) / sst) if sst > 0 else float("nan"),
        "n": n,
    }

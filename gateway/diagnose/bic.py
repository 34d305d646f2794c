"""The one ΔBIC of the diagnosis: every comparison of a model with and without a part.

    ΔBIC = n_e ln(SSE_new / SSE_old) + k ln(n_e)

with n_e the number of *effective* samples: residuals of free runs, hourly humidity means and
sunlit radiation samples are autocorrelated, so each comparison says what one independent
sample is (one per ``EFFECTIVE_S`` of residual, one per night, ...). Negative: the new model
is better by more than its ``k`` extra parameters cost.
"""

from __future__ import annotations

import numpy as np

EFFECTIVE_S = 3600.0
"""One effective sample per hour of residual: free-run residuals are autocorrelated."""


def effective_samples(n_pairs: int, dt: float, effective_s: float = EFFECTIVE_S) -> float:
    """n_e = n dt / ``effective_s``, at least 2."""
    return max(n_pairs * dt / effective_s, 2.0)


def delta_bic(sse_new: float, sse_old: float, n_effective: float, k_new: int) -> float:
    """ΔBIC of the new model against the old one (module docstring)."""
    return float(n_effective * np.log(max(sse_new, 1e-300) / max(sse_old, 1e-300))
                 + k_new * np.log(n_effective))

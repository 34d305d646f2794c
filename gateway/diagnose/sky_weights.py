"""Weights for the base calibration from the sky the kit cannot see (issue 10, nw).

The kit's sky temperature is an estimate (gateway/model/sky.py): against the measured sky of
the 51 Bleiswijk days its error spreads ± 4.58 K where the cloud is read from the daytime
radiation (r = 0) and ± 6.38 K where it is carried and relaxed towards a prior (r > 0, the
night; bias excluded, a constant the fit takes up; tests/generality/sky_study.py --night).
A calibration night the kit misreads is not noise around the model, yet an unweighted fit
treats its residual as such and distorts the parameters to explain it (the sky-loss
coefficient grows over two clear nights read as overcast, docs/effects.md, "What the night
sky the kit cannot see costs the base").

Here the sky is an unknown with that spread: each free-run sample's residual gets the weight

    w = 1 / (σ_n² + σ_T²)          (a Gaussian likelihood with known variances)

σ_T [K] the change of the free run's T_in when the sky is shifted by its spread from the
window's start on (the linear response to a fully correlated error: a misread sky is a
night-long offset; its measured autocorrelation is still 0.51 at 3 h), computed with the start
model and parameters so that the yardstick is fixed for the whole calibration and the
misread nights cannot set their own weight; σ_n the base's error once the sky is known (the
mean held-out MAE with the generators' own sky, 0.61 K, × √(π/2) for a Gaussian: 0.77 K).
The weights are normalised to mean 1 over the comparable samples, so MSE values keep their
scale in K². Measured, not adopted (base.SKY_WEIGHTS off): σ_T is only 0.3–0.7 K, nights get
0.67–0.88 × the days' weight, and the base's effect-free error rose on both tuning generators
(docs/effects.md, "Weighting the base by the sky's spread").
"""

from __future__ import annotations

import numpy as np

from gateway.diagnose.night_sky import RELAX
from gateway.diagnose.structure import Structured
from gateway.greenhouse import Greenhouse

SPREAD_READ_K = 4.58
"""[K] std of the kit's sky error where the cloud is read (r = 0), 3748 Bleiswijk rows."""
SPREAD_CARRIED_K = 6.38
"""[K] std of the kit's sky error where the cloud is carried (r > 0), 10940 Bleiswijk rows."""
NOISE_K = 0.77
"""[K] σ_n: the base's free-run error with a known sky (module docstring)."""


def sky_spread(x: dict[str, np.ndarray]) -> np.ndarray:
    """[K] the spread of the kit's sky error at each row: read (r = 0) or carried (r > 0)."""
    return np.where(x[RELAX] > 0.0, SPREAD_CARRIED_K, SPREAD_READ_K)


def sky_response(model: Structured, theta: np.ndarray, x: dict[str, np.ndarray], gh: Greenhouse,
                 dt: float, starts: np.ndarray, horizon: int) -> np.ndarray:
    """σ_T [K] (N, H): |free run with T_sky + spread − free run| from every start. Every term
    reads ``x["t_sky"]`` (with the fitted night sky level the sky is recomputed and this is 0:
    the two parts are not meant together)."""
    shifted = dict(x)
    shifted["t_sky"] = x["t_sky"] + sky_spread(x)
    runs = [model.shoot(theta[None], d, gh, dt, starts, horizon)[0] for d in (x, shifted)]
    out = np.abs(runs[1] - runs[0])
    return np.where(np.isfinite(out), out, 0.0)


def sky_weights(model: Structured, theta: np.ndarray, x: dict[str, np.ndarray], gh: Greenhouse,
                dt: float, starts: np.ndarray, horizon: int) -> np.ndarray:
    """Residual weights (N, H), 1 / (σ_n² + σ_T²) normalised to mean 1 where T_in is measured."""
    w = 1.0 / (NOISE_K**2 + sky_response(model, theta, x, gh, dt, starts, horizon) ** 2)
    if len(starts) == 0:
        return w
    seen = np.isfinite(x["t_in"][starts[:, None] + np.arange(1, horizon + 1)[None, :]])
    return w / max(float(w[seen].mean()) if seen.any() else 1.0, 1e-12)

"""Crop: logistic leaf-area growth and big-leaf transpiration.

References
----------
- Logistic growth ``dLAI/dt = r LAI (1 - LAI / LAI_max)`` (e.g. Goudriaan & van Laar 1994).
- Stanghellini (1987), PhD thesis Wageningen, ch. 4: transpiration of a greenhouse tomato crop,
  ``lambda E = (Delta R_n + 2 LAI rho c_p VPD / r_b) / (Delta + gamma (1 + r_s / r_b))`` per m2 of
  floor, with the stomatal resistance falling with radiation,
  ``r_s = r_s,min (R / (2 LAI) + 4.30) / (R / (2 LAI) + 0.54)`` (temperature, CO2 and VPD factors
  left out). This is deliberately not the Baille form used by the gateway's model.
- Monteith & Unsworth, *Principles of Environmental Physics*: slope of the saturation curve.
"""

from __future__ import annotations

import math

import numpy as np

from gateway.model.psychrometrics import CP_AIR

GAMMA = 66.5
"""Psychrometric constant at sea level [Pa K-1]."""


def logistic_lai(days: np.ndarray, lai_start: float, lai_max: float, rate: float) -> np.ndarray:
    """LAI [m2 m-2] after ``days`` [d] of logistic growth at ``rate`` [d-1] from ``lai_start``."""
    days = np.asarray(days, dtype=float)
    if lai_start <= 0.0:
        return np.zeros_like(days)
    ratio = (lai_max - lai_start) / lai_start
    return lai_max / (1.0 + ratio * np.exp(-rate * days))


def intercepted(lai: float, k_ext: float) -> float:
    """Fraction [-] of short-wave radiation intercepted by a canopy (Beer's law)."""
    return 1.0 - math.exp(-k_ext * lai)


def transpiration(r_n: float, t_air: float, vpd: float, lai: float, r_b: float,
                  r_s_min: float, rho: float) -> float:
    """Latent heat flux of transpiration lambda E [W m-2 of floor] (Stanghellini 1987).

    ``r_n`` short-wave radiation absorbed by the canopy [W m-2 floor]; ``t_air`` [°C];
    ``vpd`` [Pa]; ``lai`` [m2 m-2]; ``r_b``, ``r_s_min`` [s m-1]; ``rho`` air density [kg m-3].
    """
    if lai <= 1e-3:
        return 0.0
    p_sat = 610.78 * math.exp(17.2694 * t_air / (t_air + 237.3))
    delta = p_sat * 17.2694 * 237.3 / (t_air + 237.3) ** 2
    x = max(r_n, 0.0) / (2.0 * lai)
    r_s = r_s_min * (x + 4.30) / (x + 0.54)
    flux = (delta * r_n + 2.0 * lai * rho * CP_AIR * vpd / r_b) / (delta + GAMMA * (1.0 + r_s / r_b))
    return max(flux, 0.0)

"""Moist-air properties used by the climate models (thesis III.2–III.5, III.13, III.30).

All functions take and return numpy arrays (or floats) and broadcast.
Temperatures are in °C unless the name ends in ``_k``; pressures in kPa.

References
----------
- Tetens (1930) as given by Murray (1967): saturation vapour pressure over water.
- ASHRAE Handbook Fundamentals (2017), ch. 1: humidity ratio and moist-air density.
- Swinbank (1963), Q. J. R. Meteorol. Soc. 89: sky temperature.
- docs/model-notes.md §1 for the thesis misprints corrected here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

KELVIN = 273.15
"""Offset between °C and K [K]."""
R_DRY_AIR = 287.055
"""Specific gas constant of dry air [J kg-1 K-1]."""
P_ATM = 101.325
"""Standard atmospheric pressure [kPa]."""
EPSILON = 0.62198
"""Ratio of the molar masses of water and dry air [-] (III.3)."""
CP_AIR = 1005.0
"""Specific heat of air at constant pressure [J kg-1 K-1]."""
GRAVITY = 9.81
"""Standard gravity [m s-2]."""

# The Tetens coefficients of p_ws = A exp(B t / (t + C)) (III.5) as 0-d arrays: the same float64
# operations as with Python floats, but numpy 2 converts a Python float operand at every call,
# ~40 % of an operation on the (P, 1) arrays of a model step (the online estimator's candidates).
_TETENS_A, _TETENS_B, _TETENS_C = np.array(0.61078), np.array(17.2694), np.array(237.3)


def saturation_vapour_pressure(t: ArrayLike) -> np.ndarray:
    """Saturation vapour pressure p_ws [kPa] of air at temperature ``t`` [°C] (Tetens).

    Thesis III.5 prints the denominator with the temperature in kelvin; the Tetens form takes
    °C: ``p_ws = 0.61078 exp(17.2694 t / (t + 237.3))`` (docs/model-notes.md §1).
    """
    t = np.asarray(t, dtype=float)
    return _tetens(t, t + _TETENS_C)


def _tetens(t: np.ndarray, d: np.ndarray) -> np.ndarray:
    """p_ws [kPa] at ``t`` [°C] given d = t + 237.3 (Tetens)."""
    return _TETENS_A * np.exp(_TETENS_B * t / d)


def _tetens_slope(p_ws: np.ndarray, d: np.ndarray) -> np.ndarray:
    """d p_ws / dT [kPa K-1] given p_ws and d = t + 237.3 (the Tetens form differentiated)."""
    return p_ws * _TETENS_B * _TETENS_C / d**2


def saturation_vapour_pressure_slope(t: ArrayLike, p_ws: ArrayLike | None = None) -> np.ndarray:
    """d p_ws / dT [kPa K-1] of the Tetens form at ``t`` [°C]; ``p_ws`` when already known."""
    t = np.asarray(t, dtype=float)
    d = t + _TETENS_C
    return _tetens_slope(_tetens(t, d) if p_ws is None else np.asarray(p_ws, dtype=float), d)


def saturation_vapour_pressure_and_slope(t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(p_ws [kPa], d p_ws / dT [kPa K-1]) at ``t`` [°C], sharing the work (the exponential
    step's slope of transpiration needs both at every candidate state)."""
    t = np.asarray(t, dtype=float)
    d = t + _TETENS_C
    p_ws = _tetens(t, d)
    return p_ws, _tetens_slope(p_ws, d)


def vapour_pressure(t: ArrayLike, rh: ArrayLike) -> np.ndarray:
    """Actual vapour pressure p_w [kPa] from temperature [°C] and relative humidity [%] (III.4)."""
    return saturation_vapour_pressure(t) * np.asarray(rh, dtype=float) / 100.0


def vapour_pressure_deficit(t: ArrayLike, rh: ArrayLike) -> np.ndarray:
    """Vapour pressure deficit VPD = p_ws - p_w [kPa] from temperature [°C] and RH [%]."""
    return saturation_vapour_pressure(t) * (1.0 - np.asarray(rh, dtype=float) / 100.0)


def relative_humidity(t: ArrayLike, p_w: ArrayLike) -> np.ndarray:
    """Relative humidity [%] of air at ``t`` [°C] holding vapour pressure ``p_w`` [kPa]."""
    return 100.0 * np.asarray(p_w, dtype=float) / saturation_vapour_pressure(t)


def humidity_ratio(p_w: ArrayLike, p_atm: ArrayLike = P_ATM) -> np.ndarray:
    """Humidity ratio W [kg water per kg dry air] from vapour pressure p_w [kPa] (III.3).

    The thesis calls this a density and adds it to one (III.2); it is a mass ratio
    (docs/model-notes.md §1, ASHRAE Fundamentals eq. 22).
    """
    p_w = np.asarray(p_w, dtype=float)
    return EPSILON * p_w / (np.asarray(p_atm, dtype=float) - p_w)


def moist_air_density(t: ArrayLike, p_w: ArrayLike = 0.0, p_atm: ArrayLike = P_ATM) -> np.ndarray:
    """Density of moist air rho [kg m-3] at ``t`` [°C], vapour pressure p_w [kPa], p_atm [kPa].

    ``rho = p_atm / (R_d T) (1 - 0.378 p_w / p_atm)`` (ideal-gas mixture), used in place of the
    thesis III.2 sum of a density and a humidity ratio (docs/model-notes.md §1).
    """
    p_atm = np.asarray(p_atm, dtype=float)
    t_k = np.asarray(t, dtype=float) + KELVIN
    return p_atm * 1e3 / (R_DRY_AIR * t_k) * (1.0 - 0.378 * np.asarray(p_w, dtype=float) / p_atm)


def sky_temperature_k(t_out: ArrayLike) -> np.ndarray:
    """Clear-sky temperature T_sky [K] from outside air temperature [°C] (Swinbank; III.13).

    ``T_sky = 0.0552 T_out^1.5`` with both temperatures in kelvin.
    """
    return 0.0552 * (np.asarray(t_out, dtype=float) + KELVIN) ** 1.5


def sky_temperature(t_out: ArrayLike) -> np.ndarray:
    """Clear-sky temperature [°C] from outside air temperature [°C] (Swinbank; III.13)."""
    return sky_temperature_k(t_out) - KELVIN


def latent_heat_vaporisation(t: ArrayLike) -> np.ndarray:
    """Latent heat of vaporisation lambda [J kg-1] at crop temperature ``t`` [°C] (III.30).

    ``lambda = 4185.5 (597 - 0.56 t)``, the calorie-based form of the thesis.
    """
    return 4185.5 * (597.0 - 0.56 * np.asarray(t, dtype=float))

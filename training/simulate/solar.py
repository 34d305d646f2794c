"""Solar geometry and clear-sky global radiation for synthetic weather.

References
----------
- Cooper (1969), Solar Energy 12: solar declination.
- Spencer-type equation of time as given by Duffie & Beckman, *Solar Engineering of Thermal
  Processes* (4th ed., 2013), eq. 1.5.3 (simplified 3-term form).
- Haurwitz (1945), J. Meteorol. 2: clear-sky global horizontal irradiance
  ``G = 1098 cos(z) exp(-0.057 / cos(z))`` [W m-2].
- Kasten & Czeplak (1980), Solar Energy 24: cloud attenuation ``1 - 0.75 c^3.4``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

SECONDS_PER_DAY = 86400.0


def day_of_year(time: np.ndarray) -> np.ndarray:
    """Fractional day of year [d] (1.0 = 1 January 00:00 UTC) of datetime64 instants."""
    t = np.asarray(time, dtype="datetime64[s]")
    year_start = t.astype("datetime64[Y]").astype("datetime64[s]")
    return 1.0 + (t - year_start).astype(np.int64) / SECONDS_PER_DAY


def cos_zenith(time: np.ndarray, latitude: float, longitude: float) -> np.ndarray:
    """Cosine of the solar zenith angle [-] at UTC ``time``, site ``latitude``/``longitude`` [deg].

    Negative values mean the sun is below the horizon.
    """
    n = day_of_year(time)
    decl = np.radians(23.45) * np.sin(2.0 * np.pi * (284.0 + n) / 365.0)
    b = 2.0 * np.pi * (n - 81.0) / 364.0
    eot_min = 9.87 * np.sin(2.0 * b) - 7.53 * np.cos(b) - 1.5 * np.sin(b)
    utc_hour = (n - np.floor(n)) * 24.0
    solar_hour = utc_hour + longitude / 15.0 + eot_min / 60.0
    omega = np.radians(15.0 * (solar_hour - 12.0))
    phi = np.radians(latitude)
    return np.sin(phi) * np.sin(decl) + np.cos(phi) * np.cos(decl) * np.cos(omega)


def solar_hour(time: np.ndarray, longitude: float) -> np.ndarray:
    """Apparent solar time of day [h] (12 = solar noon), ignoring the equation of time."""
    n = day_of_year(time)
    return np.mod((n - np.floor(n)) * 24.0 + longitude / 15.0, 24.0)


def clear_sky_global(cos_z: ArrayLike) -> np.ndarray:
    """Clear-sky global horizontal irradiance [W m-2] from cos(zenith) [-] (Haurwitz 1945)."""
    mu = np.asarray(cos_z, dtype=float)
    out = np.zeros_like(mu)
    up = mu > 0.01
    out[up] = 1098.0 * mu[up] * np.exp(-0.057 / mu[up])
    return out


def cloud_transmission(cloud: ArrayLike) -> np.ndarray:
    """Fraction [-] of clear-sky global radiation left under cloud cover ``cloud`` [0-1]."""
    c = np.clip(np.asarray(cloud, dtype=float), 0.0, 1.0)
    return 1.0 - 0.75 * c**3.4

"""Solar position and clear-sky global radiation at a site, from UTC time alone.

The kit measures global radiation but no cloud cover; comparing the measurement with the
radiation a clear sky would give (the clear-sky index) tells how cloudy it is. Both need the
sun's position at the greenhouse's latitude and longitude (``[site]`` in the greenhouse TOML).

References
----------
- NOAA Global Monitoring Laboratory, "Solar Calculation Details" (general solar position
  spreadsheet, after J. Meeus, *Astronomical Algorithms*, 1991): declination, equation of time,
  hour angle, Sun–Earth distance. Accuracy about 0.01° in zenith for 1800–2100.
- Haurwitz (1945), "Insolation in relation to cloudiness and cloud density", J. Meteorol. 2,
  154–166: clear-sky global horizontal irradiance ``G = 1098 cos z exp(-0.059 / cos z)``
  [W m-2], as implemented in pvlib ``clearsky.haurwitz``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

SOLAR_CONSTANT = 1361.0
"""Total solar irradiance at 1 au [W m-2] (Kopp & Lean 2011)."""

MIN_COS_ZENITH = 0.01
"""Below this cos z (sun under ~0.6° of elevation) the clear-sky radiation is taken as 0."""

DAY_S = 86400
"""A mean solar day [s]."""


def measured_global(i_glob: ArrayLike) -> np.ndarray:
    """Measured global radiation [W m-2] as every part of the gateway reads it: a
    pyranometer's small negative offset at night (the kit CSV accepts down to -10 W m-2,
    gateway/kitcsv.py) counts as 0, and a missing value (NaN) stays missing. The one place
    of this rule: the model's drivers (drivers.py), the cloudiness read from the radiation,
    whole series or one sample at a time (sky.py), the live gateway's weather outlook
    (gateway/estimate/horizon.py ``live_block``; replay's reads the drivers)."""
    return np.maximum(np.asarray(i_glob, dtype=float), 0.0)


@dataclass(frozen=True)
class SolarPosition:
    """Sun's position for each instant (arrays of the shape of the time argument).

    ``cos_zenith`` [-] (negative below the horizon), ``declination`` [deg],
    ``equation_of_time`` [min], ``hour_angle`` [deg] (0 at solar noon, positive afternoon),
    ``distance`` Sun–Earth [au].
    """

    cos_zenith: np.ndarray
    declination: np.ndarray
    equation_of_time: np.ndarray
    hour_angle: np.ndarray
    distance: np.ndarray

    @property
    def zenith(self) -> np.ndarray:
        """Solar zenith angle [deg], no refraction."""
        return np.degrees(np.arccos(np.clip(self.cos_zenith, -1.0, 1.0)))

    @property
    def elevation(self) -> np.ndarray:
        """Solar elevation [deg] above the horizon, no refraction."""
        return 90.0 - self.zenith


def mean_solar_offset_min(longitude: ArrayLike) -> np.ndarray:
    """Local mean solar time minus UTC [min] at ``longitude`` [deg, east positive]: the Earth
    turns 1° in 4 min (NOAA; the true solar time adds the equation of time)."""
    return 4.0 * np.asarray(longitude, dtype=float)


CLOCK_STEP_S = 1800
"""The clock of the time-of-day features keeps whole half-hours from UTC [s]: a grower's
controller runs on civil time, whole (in a few zones half) hours from UTC, so its scheduled
actions stay on the diagnosis's half-hour bins."""


@dataclass(frozen=True)
class SolarClock:
    """The clock of the time-of-day features (docs/effects.md, "The clock of the time-of-day
    features"): local mean solar time at the site to the nearest half hour, so that noon is noon
    (within 15 min) and a day starts at local midnight wherever the greenhouse stands; UTC when
    no site is known. ``offset_s`` [s] is added to UTC; ``name`` is what labels say ("local
    solar time", "UTC (no site)")."""

    offset_s: int
    name: str

    def seconds(self, time: np.ndarray) -> np.ndarray:
        """Seconds of this clock since its 1970-01-01 00:00 (int64) at UTC ``time``
        (datetime64): ``% DAY_S`` is the time of day, ``// DAY_S`` the day."""
        return np.asarray(time, dtype="datetime64[s]").astype(np.int64) + self.offset_s


def solar_clock(longitude: float | None) -> SolarClock:
    """The ``SolarClock`` of a site at ``longitude`` [deg, east positive]: its mean solar
    offset rounded to whole ``CLOCK_STEP_S`` (Almería, −2.7°: UTC; Bleiswijk, 4.5°: UTC + 30
    min; −90°: UTC − 6 h); None (no ``[site]``): UTC, named so."""
    if longitude is None:
        return SolarClock(0, "UTC (no site)")
    offset_s = 60.0 * float(mean_solar_offset_min(longitude))
    return SolarClock(int(round(offset_s / CLOCK_STEP_S)) * CLOCK_STEP_S, "local solar time")


UTC_CLOCK = solar_clock(None)
"""The clock of callers that know no site."""


def _unix_seconds(time: np.ndarray) -> np.ndarray:
    return np.asarray(time, dtype="datetime64[s]").astype(np.int64).astype(float)


def solar_position(time: np.ndarray, latitude: float, longitude: float) -> SolarPosition:
    """Sun's position at UTC ``time`` (datetime64) for a site at ``latitude`` [deg, north
    positive] and ``longitude`` [deg, east positive] (NOAA solar calculation)."""
    if not -90.0 <= latitude <= 90.0:
        raise ValueError(f"latitude must be within [-90, 90] deg, got {latitude}")
    if not -180.0 <= longitude <= 180.0:
        raise ValueError(f"longitude must be within [-180, 180] deg, got {longitude}")
    unix = _unix_seconds(time)
    jc = (unix / 86400.0 + 2440587.5 - 2451545.0) / 36525.0  # Julian century (J2000)
    mean_long = np.mod(280.46646 + jc * (36000.76983 + jc * 0.0003032), 360.0)  # [deg]
    mean_anom = 357.52911 + jc * (35999.05029 - 0.0001537 * jc)  # [deg]
    ecc = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc)  # [-]
    m = np.radians(mean_anom)
    centre = (np.sin(m) * (1.914602 - jc * (0.004817 + 0.000014 * jc))
              + np.sin(2 * m) * (0.019993 - 0.000101 * jc) + np.sin(3 * m) * 0.000289)
    true_anom = np.radians(mean_anom + centre)
    distance = 1.000001018 * (1 - ecc**2) / (1 + ecc * np.cos(true_anom))  # [au]
    omega = np.radians(125.04 - 1934.136 * jc)
    app_long = np.radians(mean_long + centre - 0.00569 - 0.00478 * np.sin(omega))
    mean_obliq = 23.0 + (26.0 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60.0) / 60.0
    obliq = np.radians(mean_obliq + 0.00256 * np.cos(omega))
    decl = np.arcsin(np.sin(obliq) * np.sin(app_long))
    y = np.tan(obliq / 2) ** 2
    l0 = np.radians(mean_long)
    eot = 4.0 * np.degrees(  # [min]
        y * np.sin(2 * l0) - 2 * ecc * np.sin(m) + 4 * ecc * y * np.sin(m) * np.cos(2 * l0)
        - 0.5 * y**2 * np.sin(4 * l0) - 1.25 * ecc**2 * np.sin(2 * m))
    minutes_utc = np.mod(unix, 86400.0) / 60.0
    true_solar_time = np.mod(minutes_utc + eot + mean_solar_offset_min(longitude), 1440.0)  # [min]
    hour_angle = true_solar_time / 4.0 - 180.0  # [deg]
    phi = np.radians(latitude)
    cos_z = np.sin(phi) * np.sin(decl) + np.cos(phi) * np.cos(decl) * np.cos(np.radians(hour_angle))
    return SolarPosition(cos_z, np.degrees(decl), eot, hour_angle, distance)


def extraterrestrial_horizontal(position: SolarPosition) -> np.ndarray:
    """Radiation on a horizontal plane at the top of the atmosphere [W m-2] (0 at night)."""
    return SOLAR_CONSTANT / position.distance**2 * np.maximum(position.cos_zenith, 0.0)


def clear_sky_global(cos_zenith: np.ndarray) -> np.ndarray:
    """Clear-sky global horizontal irradiance [W m-2] from cos z [-] (Haurwitz 1945)."""
    mu = np.asarray(cos_zenith, dtype=float)
    up = mu > MIN_COS_ZENITH
    safe = np.where(up, mu, 1.0)
    return np.where(up, 1098.0 * safe * np.exp(-0.059 / safe), 0.0)


def clear_sky_index(
    i_glob: np.ndarray, time: np.ndarray, latitude: float, longitude: float,
    min_clear_sky: float = 50.0,
) -> np.ndarray:
    """Measured over clear-sky global radiation [-], NaN where the clear sky gives less than
    ``min_clear_sky`` [W m-2] (night, low sun: the ratio there is noise)."""
    clear = clear_sky_global(solar_position(time, latitude, longitude).cos_zenith)
    measured = np.asarray(i_glob, dtype=float)
    ok = clear >= min_clear_sky
    return np.where(ok, measured / np.where(ok, clear, 1.0), np.nan)

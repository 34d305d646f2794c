"""Outside weather that drives the simulator: real Bleiswijk data or synthetic Biskra/Almería days.

Every source returns a :class:`Weather` on a regular grid of ``step`` seconds (UTC).

The Bleiswijk file (``training/data/bleiswijk/``, GreenLight 2.0.5 test data, licence kept
beside it) is in local standard time (CET = UTC+1); it is shifted to UTC here.

Synthetic days are built from solar geometry (:mod:`training.simulate.solar`), a seeded cloud
factor per day with intra-day fluctuation, a diurnal temperature cycle (maximum ~14:30 solar
time, amplitude reduced under cloud), a daily vapour pressure (RH follows the temperature), a
daily mean wind with an afternoon breeze and gusts, and the sky temperature of Swinbank (1963)
blended with the cloud-base temperature (cloudy skies radiate near air temperature).
Climate normals are rough monthly values for Biskra (Köppen BWh), Almería (BSh) and Sevilla (Csa,
hot-dry inland summers; opt-in training data of the virtual sensor, docs/vsensor.md).
"""

from __future__ import annotations

import gzip
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from gateway.model.psychrometrics import KELVIN, saturation_vapour_pressure, sky_temperature
from training.simulate import solar

DATA_DIR = Path(__file__).resolve().parent.parent / "data" / "bleiswijk"
BLEISWIJK_FILE = DATA_DIR / "bleiswijk_weather_5min.csv.gz"
BLEISWIJK_T0_UTC = np.datetime64("2009-10-19T23:00:00", "s")
"""First row of the Bleiswijk file: 2009-10-20 00:00 CET = 2009-10-19 23:00 UTC."""
BLEISWIJK_LATITUDE = 52.03
BLEISWIJK_LONGITUDE = 4.53
RAIN_RH_PROXY = 98.0
"""Outside RH [%] at or above which the rain detector is taken as wet (Bleiswijk has no rain)."""


@dataclass
class Weather:
    """Outside conditions on a regular grid.

    Attributes: ``time`` datetime64[s] UTC; ``t_out`` [°C]; ``rh_out`` [%]; ``i_glob`` global
    horizontal radiation [W m-2]; ``wind`` [m s-1]; ``t_sky`` apparent sky temperature [°C];
    ``rain`` detector state [0/1]; ``source`` a short name; ``latitude`` [deg].
    """

    time: np.ndarray
    t_out: np.ndarray
    rh_out: np.ndarray
    i_glob: np.ndarray
    wind: np.ndarray
    t_sky: np.ndarray
    rain: np.ndarray
    source: str
    latitude: float
    notes: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.time)

    def seconds(self) -> np.ndarray:
        """Times as float seconds since the Unix epoch."""
        return self.time.astype("datetime64[s]").astype(np.int64).astype(float)


@dataclass(frozen=True)
class Climate:
    """Rough climate normals of a site for synthetic weather.

    ``t_mean_winter``/``t_mean_summer`` daily mean air temperature [°C] mid-January/mid-July;
    ``range_winter``/``range_summer`` clear-day diurnal range [K]; ``e_winter``/``e_summer``
    vapour pressure [kPa]; ``p_cloudy_winter``/``p_cloudy_summer`` probability [-] of an
    overcast day; ``wind_mean`` [m s-1]; ``latitude``/``longitude`` [deg].
    """

    latitude: float
    longitude: float
    t_mean_winter: float
    t_mean_summer: float
    range_winter: float
    range_summer: float
    e_winter: float
    e_summer: float
    p_cloudy_winter: float
    p_cloudy_summer: float
    wind_mean: float


CLIMATES: dict[str, Climate] = {
    # M'ziraa, Biskra (thesis §II.2.1): hot desert, large diurnal range, dry air.
    "biskra": Climate(34.722, 6.294, 11.5, 34.0, 13.0, 15.0, 0.75, 1.30, 0.12, 0.03, 4.0),
    # Las Palmerillas, Almería (thesis §II.3.1): mild, humid sea air, small diurnal range.
    "almeria": Climate(36.793, -2.720, 12.5, 26.0, 7.5, 8.0, 0.95, 2.20, 0.25, 0.05, 4.0),
    # Sevilla Aeropuerto, AEMET normals 1981-2010, rounded (Jan/Jul mean 10.9/28.2 °C, max - min
    # 10.3/15.7 K): an inland hot-dry site, the climate type a Mediterranean/North-African grower
    # sees and the two sites above do not (mild sea air; the Dutch file). Chosen for its type
    # before any measurement, and not the test site (vsensor corpus HOT_DRY, eleventh pass).
    "seville": Climate(37.42, -5.90, 10.9, 28.2, 10.3, 15.7, 1.00, 1.65, 0.20, 0.02, 3.0),
}
WEATHER_SOURCES = ("bleiswijk", *CLIMATES)
DEFAULT_START = {
    "bleiswijk": "2009-11-01",
    "biskra": "2019-01-26",
    "almeria": "2020-03-01",
    "seville": "2021-07-12",
}


def parse_start(text: str | np.datetime64) -> np.datetime64:
    """A start instant 'YYYY-MM-DD[THH:MM[:SS]][Z]' (UTC) as datetime64[s]."""
    if isinstance(text, np.datetime64):
        return text.astype("datetime64[s]")
    try:
        return np.datetime64(str(text).strip().rstrip("Z"), "s")
    except ValueError:
        raise ValueError(f"bad start time {text!r}; write YYYY-MM-DD[THH:MM] (UTC)") from None


def load_weather(
    source: str, start: np.datetime64, days: float, step: float = 60.0, seed: int = 0
) -> Weather:
    """Weather from ``source`` ('bleiswijk' or a key of :data:`CLIMATES`) for ``days`` [d] from ``start``.

    ``step`` is the grid step [s]; ``seed`` only matters for synthetic sources.
    """
    if source == "bleiswijk":
        return bleiswijk(start, days, step)
    if source in CLIMATES:
        return synthetic(source, start, days, step, seed)
    raise ValueError(f"unknown weather source {source!r}; known: {', '.join(WEATHER_SOURCES)}")


@lru_cache(maxsize=1)
def _bleiswijk_table() -> np.ndarray:
    with gzip.open(BLEISWIJK_FILE, "rt", encoding="utf-8") as handle:
        return np.loadtxt(handle, delimiter=",", skiprows=3)


def bleiswijk_range() -> tuple[np.datetime64, np.datetime64]:
    """First and last instant (UTC) covered by the shipped Bleiswijk file."""
    seconds = _bleiswijk_table()[:, 0]
    return (
        BLEISWIJK_T0_UTC + np.timedelta64(int(seconds[0]), "s"),
        BLEISWIJK_T0_UTC + np.timedelta64(int(seconds[-1]), "s"),
    )


def bleiswijk(start: np.datetime64, days: float, step: float = 60.0) -> Weather:
    """Measured Bleiswijk weather interpolated linearly from 5 min to ``step`` [s].

    RH follows from vpOut [Pa] and tOut [°C]; the sky temperature is the file's tSky; the rain
    column is a proxy (outside RH >= :data:`RAIN_RH_PROXY`).
    """
    table = _bleiswijk_table()
    time = _grid(start, days, step)
    first, last = bleiswijk_range()
    if time[0] < first or time[-1] > last:
        raise ValueError(
            f"Bleiswijk weather covers {first}Z to {last}Z; asked for {time[0]}Z to {time[-1]}Z"
        )
    x = (time - BLEISWIJK_T0_UTC).astype(np.int64).astype(float)
    col = {name: i for i, name in enumerate(
        ("Time", "tOut", "vpOut", "co2Out", "wind", "tSky", "tSoOut", "iGlob"))}

    def interp(name: str) -> np.ndarray:
        return np.interp(x, table[:, 0], table[:, col[name]])

    t_out = interp("tOut")
    rh_out = np.clip(100.0 * interp("vpOut") / 1000.0 / saturation_vapour_pressure(t_out), 1, 100)
    return Weather(
        time=time,
        t_out=t_out,
        rh_out=rh_out,
        i_glob=np.maximum(interp("iGlob"), 0.0),
        wind=np.maximum(interp("wind"), 0.0),
        t_sky=interp("tSky"),
        rain=(rh_out >= RAIN_RH_PROXY).astype(float),
        source="bleiswijk",
        latitude=BLEISWIJK_LATITUDE,
        notes={"file": "training/data/bleiswijk/bleiswijk_weather_5min.csv.gz",
               "licence": "training/data/bleiswijk/LICENSE-GreenLight.txt",
               "time_zone": "file is CET (UTC+1), shifted to UTC",
               "rain": f"proxy: rh_out >= {RAIN_RH_PROXY} %"},
    )


def _grid(start: np.datetime64, days: float, step: float) -> np.ndarray:
    n = int(round(days * solar.SECONDS_PER_DAY / step))
    if n < 2:
        raise ValueError(f"need at least two samples, got days={days}, step={step}")
    offsets = np.round(np.arange(n) * step).astype(np.int64)
    return np.datetime64(start, "s") + offsets.astype("timedelta64[s]")


def _ar1(rng: np.random.Generator, n: int, tau_steps: float, sigma: float) -> np.ndarray:
    """Stationary AR(1) noise of standard deviation ``sigma`` and correlation time ``tau_steps``."""
    a = float(np.exp(-1.0 / max(tau_steps, 1e-9)))
    shocks = rng.normal(0.0, sigma * np.sqrt(1.0 - a * a), n)
    out = np.empty(n)
    acc = rng.normal(0.0, sigma)
    for i in range(n):  # short loop (one value per step), clearer than a filter call
        acc = a * acc + shocks[i]
        out[i] = acc
    return out


def synthetic(site: str, start: np.datetime64, days: float, step: float = 60.0,
              seed: int = 0) -> Weather:
    """Seeded synthetic clear-sky/cloudy days for ``site`` (a key of :data:`CLIMATES`)."""
    clim = CLIMATES[site]
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7919, len(site)]))
    time = _grid(start, days, step)
    n = len(time)
    doy = solar.day_of_year(time)
    season = 0.5 * (1.0 - np.cos(2.0 * np.pi * (doy - 20.0) / 365.0))  # 0 mid-Jan, 1 mid-Jul

    # One cloud amount and one weather anomaly per calendar day, smoothly joined.
    day_index = ((time - time[0].astype("datetime64[D]")).astype(np.int64) // 86400).astype(int)
    n_days = int(day_index[-1]) + 2
    p_cloudy = clim.p_cloudy_winter + (clim.p_cloudy_summer - clim.p_cloudy_winter) * season[0]
    overcast = rng.random(n_days) < p_cloudy
    cloud_day = np.where(overcast, rng.uniform(0.6, 0.95, n_days), rng.uniform(0.0, 0.25, n_days))
    t_anom_day = np.cumsum(rng.normal(0.0, 1.2, n_days)) * 0.6
    e_factor_day = np.exp(rng.normal(0.0, 0.15, n_days))
    wind_day = clim.wind_mean * rng.gamma(4.0, 0.25, n_days)
    day_pos = (time - time[0].astype("datetime64[D]")).astype(np.int64) / 86400.0 - 0.5

    def daily(values: np.ndarray) -> np.ndarray:
        return np.interp(day_pos, np.arange(n_days), values)

    steps_per_hour = 3600.0 / step
    cloud = np.clip(daily(cloud_day) + _ar1(rng, n, 0.4 * steps_per_hour, 0.12)
                    * (0.3 + daily(cloud_day)), 0.0, 1.0)
    cos_z = solar.cos_zenith(time, clim.latitude, clim.longitude)
    i_glob = solar.clear_sky_global(cos_z) * solar.cloud_transmission(cloud)

    hour = solar.solar_hour(time, clim.longitude)
    t_mean = clim.t_mean_winter + (clim.t_mean_summer - clim.t_mean_winter) * season
    t_range = (clim.range_winter + (clim.range_summer - clim.range_winter) * season) * (
        1.0 - 0.6 * daily(cloud_day))
    t_out = (t_mean + daily(t_anom_day) + 0.5 * t_range * np.cos(2 * np.pi * (hour - 14.5) / 24)
             + _ar1(rng, n, 0.5 * steps_per_hour, 0.3))

    e_out = (clim.e_winter + (clim.e_summer - clim.e_winter) * season) * daily(e_factor_day)
    rain = np.zeros(n)
    for d in np.flatnonzero(overcast & (rng.random(n_days) < 0.5)):
        begin = rng.uniform(0.0, 21.0)
        hours = (time - time[0].astype("datetime64[D]")).astype(np.int64) / 3600.0 - 24.0 * d
        rain[(hours >= begin) & (hours < begin + rng.uniform(1.0, 3.0))] = 1.0
    p_sat = saturation_vapour_pressure(t_out)
    e_out = np.minimum(e_out, np.where(rain > 0, 0.98, 0.95) * p_sat)
    e_out = np.where(rain > 0, 0.97 * p_sat, e_out)
    rh_out = 100.0 * e_out / p_sat

    breeze = 1.0 + 0.4 * np.cos(2 * np.pi * (hour - 15.0) / 24)
    wind = np.maximum(daily(wind_day) * breeze * (1.0 + _ar1(rng, n, 0.1 * steps_per_hour, 0.25)),
                      0.0)

    t_clear_k = sky_temperature(t_out) + KELVIN
    t_cloud_k = t_out + KELVIN - 3.0
    t_sky = ((1.0 - cloud) * t_clear_k**4 + cloud * t_cloud_k**4) ** 0.25 - KELVIN
    return Weather(
        time=time, t_out=t_out, rh_out=rh_out, i_glob=i_glob, wind=wind, t_sky=t_sky,
        rain=rain, source=site, latitude=clim.latitude,
        notes={"synthetic": True, "seed": int(seed),
               "cloud_per_day": [round(float(c), 3) for c in cloud_day[:n_days - 1]]},
    )

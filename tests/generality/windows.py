"""Weather windows for the generality study: real Bleiswijk weather and a Mediterranean-like
summer made from it by shifting and scaling.

Every window is outside weather on a 60 s grid (UTC) with the site it belongs to, so that a
generator and the model agree on where the sun is. Generators take it through
:meth:`Window.sim_weather` (training/simulate) or :meth:`Window.twonode_weather`
(tests/twonode.py).

- ``autumn``: Bleiswijk 2009-10-20 + 14 d (the sunniest part of the file, many clear nights).
- ``winter``: Bleiswijk 2009-11-25 + 14 d (short, dull days, windier).
- ``summer``: the autumn window moved to 10–24 June at Almería (36.79 N, 2.72 W). Its clear-sky
  index k (the measured cloudiness) is kept, its deficit 1 - k scaled by 0.4 (a sunnier sky),
  and applied to Almería's June clear sky, day by day from sunrise to sunset; the outside
  temperature keeps its day-to-day anomalies with a daily range × 1.8 around a mean of 24 °C;
  the vapour pressure is × 1.6 (≤ 95 % of saturation); the sky keeps its measured depression
  below the air; wind is unchanged.
- ``bleiswijk_window(start, days)``: any other stretch of the file (e.g. for effect-free runs on
  many windows).

Note: in the Bleiswijk file the radiation lags the computed sun by roughly half an hour (hourly
means stamped at the end of the hour, interpolated): at low sun the clear-sky index is far
from 1 (afternoons up to 2–3), so cloudiness should be read where the clear sky is strong.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.model import solar
from gateway.model.psychrometrics import saturation_vapour_pressure
from training.simulate.weather import BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE, Weather, bleiswijk

ALMERIA = (36.79, -2.72)
BLEISWIJK = (BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE)
STEP = 60.0
CLOUD_SCALE = 0.4
"""Summer: the cloud deficit 1 - k of the clear-sky index k is scaled by this."""
SUMMER_SHIFT = np.datetime64("2009-06-10T00:00:00") - np.datetime64("2009-10-20T00:00:00")


@dataclass(frozen=True)
class Window:
    """Outside weather (arrays on one 60 s grid) and the site it belongs to."""

    name: str
    time: np.ndarray  # datetime64[s] UTC
    t_out: np.ndarray  # [°C]
    rh_out: np.ndarray  # [%]
    i_glob: np.ndarray  # [W m-2]
    wind: np.ndarray  # [m s-1]
    t_sky: np.ndarray  # [°C] apparent sky temperature (measured, or shifted with the air)
    latitude: float  # [deg N]
    longitude: float  # [deg E]

    @property
    def vapour_pressure(self) -> np.ndarray:
        """[kPa]"""
        return saturation_vapour_pressure(self.t_out) * self.rh_out / 100.0

    @property
    def start(self) -> np.datetime64:
        return self.time[0]

    def at_day(self, day: float) -> np.datetime64:
        """The instant ``day`` days after the window's start."""
        return self.time[0] + np.timedelta64(int(round(day * 86400)), "s")

    def sim_weather(self) -> Weather:
        """The window for training.simulate.simulate(weather=...)."""
        return Weather(time=self.time, t_out=self.t_out, rh_out=self.rh_out, i_glob=self.i_glob,
                       wind=self.wind, t_sky=self.t_sky, rain=(self.rh_out >= 98.0).astype(float),
                       source=f"window:{self.name}", latitude=self.latitude)

    def twonode_weather(self) -> dict[str, np.ndarray]:
        """The window for tests/twonode.simulate(weather=..., site=...): vp in Pa."""
        return {"time": self.time, "t_out": self.t_out, "rh_out": self.rh_out,
                "vp": 1000.0 * self.vapour_pressure, "wind": self.wind, "i_glob": self.i_glob}

    def site_toml(self) -> str:
        """A ``[site]`` table for a greenhouse TOML describing where this weather was made."""
        return f"[site]\nlatitude = {self.latitude}\nlongitude = {self.longitude}\n"


def bleiswijk_window(start: str, days: float = 14.0, name: str | None = None) -> Window:
    """A stretch of the shipped Bleiswijk weather from ``start`` (UTC)."""
    w = bleiswijk(np.datetime64(start, "s"), days, STEP)
    return Window(name or f"bleiswijk-{start[:10]}", w.time, w.t_out, w.rh_out, w.i_glob, w.wind,
                  w.t_sky, *BLEISWIJK)


def _daylight_map(time_src: np.ndarray, time_dst: np.ndarray, src_site: tuple[float, float],
                  dst_site: tuple[float, float]) -> np.ndarray:
    """For each destination instant in daylight, the source instant at the same fraction of its
    own day's daylight (sunrise → sunset); NaN at night. Same number of days in both."""
    up_src = solar.solar_position(time_src, *src_site).cos_zenith > 0
    up_dst = solar.solar_position(time_dst, *dst_site).cos_zenith > 0
    t_src = (time_src - time_src[0]).astype(np.int64).astype(float)
    out = np.full(len(time_dst), np.nan)
    day = 1440  # samples a day on the 60 s grid
    for d in range(len(time_dst) // day + 1):
        s = np.flatnonzero(up_src[d * day:(d + 1) * day]) + d * day
        k = np.flatnonzero(up_dst[d * day:(d + 1) * day]) + d * day
        if len(s) < 2 or len(k) < 2:
            continue
        frac = (k - k[0]) / (k[-1] - k[0])
        out[k] = t_src[s[0]] + frac * (t_src[s[-1]] - t_src[s[0]])
    return out


def summer(source: Window | None = None) -> Window:
    """A Mediterranean-like June at Almería made from ``source`` (default: the autumn window)."""
    src = source or WINDOWS["autumn"]()
    time = src.time + SUMMER_SHIFT
    clear_src = solar.clear_sky_global(solar.solar_position(src.time, src.latitude,
                                                            src.longitude).cos_zenith)
    ok = clear_src >= 20.0
    t_src = (src.time - src.time[0]).astype(np.int64).astype(float)
    k_src = np.interp(t_src, t_src[ok], np.clip(src.i_glob[ok] / clear_src[ok], 0.0, 1.2))
    where = _daylight_map(src.time, time, (src.latitude, src.longitude), ALMERIA)
    k = np.where(np.isfinite(where), np.interp(np.nan_to_num(where), t_src, k_src), 0.0)
    k = 1.0 - CLOUD_SCALE * (1.0 - k)  # fewer, thinner clouds than a Dutch autumn
    i_glob = k * solar.clear_sky_global(solar.solar_position(time, *ALMERIA).cos_zenith)
    # Daily mean (24 h running) and anomaly; the range widened, the mean moved to 24 °C.
    kernel = np.ones(1440) / 1440
    mean = np.convolve(np.pad(src.t_out, (720, 719), mode="edge"), kernel, "valid")
    t_out = 24.0 + (mean - mean.mean()) + 1.8 * (src.t_out - mean)
    e = np.minimum(1.6 * src.vapour_pressure, 0.95 * saturation_vapour_pressure(t_out))
    rh_out = 100.0 * e / saturation_vapour_pressure(t_out)
    t_sky = src.t_sky + (t_out - src.t_out)
    return Window("summer", time, t_out, rh_out, i_glob, src.wind.copy(), t_sky, *ALMERIA)


WINDOWS = {
    "autumn": lambda: bleiswijk_window("2009-10-20T00:00", 14.0, "autumn"),
    "winter": lambda: bleiswijk_window("2009-11-25T00:00", 14.0, "winter"),
    "summer": lambda: summer(),
}
"""The three windows of the generality table, by name (each call builds it afresh)."""


def load_window(name: str) -> Window:
    if name not in WINDOWS:
        raise ValueError(f"unknown window {name!r}; known: {', '.join(WINDOWS)}")
    return WINDOWS[name]()

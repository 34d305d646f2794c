"""``clear-sky-trend``: a causal weather outlook from the sun's geometry and the recent weather.

What the live gateway uses instead of the coming weather it cannot know (issue 10):

- **Radiation** = clear-sky radiation (Haurwitz, at the site's computed sun position) at the
  coming instants × the current clear-sky index. The index is a ratio of sums over the last
  ``index_window`` (measured / clear sky) of the samples whose clear sky is strong (≥ 50 W m-2),
  so weak low-sun samples, whose ratio is noise, barely count; through the night and the first
  weak light of the morning it keeps its last value (the previous afternoon's cloudiness).
  Measured radiation can lag the computed sun (logger averages stamped at the end of the
  interval: the Bleiswijk file's hourly means run ~30 min late, tests/generality/windows.py),
  which makes the ratio at low sun far from 1 (afternoons up to 2-3): the strong-sun weighting
  and the short window keep the index usable there. A lag estimated from past days (daily
  cross-correlation with the clear sky) was tried and did not pay: on the Bleiswijk tuning
  stretch 2009-11-04..24 it made the 15-60 min radiation error 4-6 % larger, and it found a
  spurious 5-15 min lag in data with none (docs/online-estimator.md, "Weather outlook").
- **Outside temperature** = its level now (end of a straight line fitted to the last
  ``trend_window``, which filters sensor noise and 0.1 K steps) + ``shape_weight`` × the change
  the previous days made over the same clock interval (the daily shape, mean over up to
  ``shape_days`` days) + the current trend, damped with e-folding time ``trend_damping``.
- **Outside humidity**: the vapour pressure is carried (level now, damped trend), and the
  relative humidity follows from it at the forecast temperature (the air's moisture changes
  more slowly than its RH).
- **Wind** is held at its mean over the last ``wind_window`` (the anemometer's 0.47 m/s steps
  averaged out).
- Every other column (inside readings, vents, LAI) is held at its latest finite value.

Only values at or before "now" are read. ``drivers_at`` serves many start times at once (one
numpy pass per horizon step, no loop per start), for ``replay``'s report; ``drivers`` is the
single-start :class:`~gateway.estimate.outlook.Outlook` call of the live gateway.

References: Haurwitz (1945) clear sky and the NOAA solar position (gateway/model/solar.py);
clear-sky-index persistence as the reference short-term irradiance forecast: Yang et al.
(2020), "Verification of deterministic solar forecasts", Solar Energy 210, 20-37, §3.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from gateway.greenhouse import Greenhouse, Site
from gateway.model.psychrometrics import saturation_vapour_pressure
from gateway.model.solar import clear_sky_global, solar_position

DAY_S = 86400.0


def _unix(time: np.ndarray) -> np.ndarray:
    return np.asarray(time, dtype="datetime64[s]").astype(np.int64).astype(float)


def _trailing_sums(values: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum and count of the finite values in the last ``window`` samples up to each index."""
    ok = np.isfinite(values)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, values, 0.0))])
    n = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return c[idx] - c[lo], (n[idx] - n[lo]).astype(float)


def trailing_line(values: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Level at each index and slope [per sample] of a least-squares line through the finite
    values of the last ``window`` samples (NaN with fewer than 3 values)."""
    v = np.asarray(values, dtype=float)
    k = np.arange(len(v), dtype=float)
    ok = np.isfinite(v)
    s0 = _trailing_sums(np.where(ok, 1.0, np.nan), window)[0]
    s1 = _trailing_sums(np.where(ok, k, np.nan), window)[0]
    s2 = _trailing_sums(np.where(ok, k * k, np.nan), window)[0]
    sy = _trailing_sums(v, window)[0]
    sky = _trailing_sums(np.where(ok, k * v, np.nan), window)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        det = s0 * s2 - s1 * s1
        slope = np.where(det > 0, (s0 * sky - s1 * sy) / np.where(det > 0, det, 1.0), 0.0)
        level = np.where(s0 > 0, (sy - slope * s1) / np.where(s0 > 0, s0, 1.0) + slope * k, np.nan)
    few = s0 < 3
    level = np.where(few, forward_fill(v), level)
    slope = np.where(few, 0.0, slope)
    return level, slope


def forward_fill(v: np.ndarray) -> np.ndarray:
    """Latest finite value at or before each index (NaN before the first)."""
    ok = np.isfinite(v)
    idx = np.where(ok, np.arange(len(v)), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, v[np.maximum(idx, 0)], np.nan)


def daily_shape(t_out: np.ndarray, starts: np.ndarray, k: np.ndarray, dt: float, days: int,
                scale: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """(N, len(k)) mean change of ``t_out`` over the last ``days`` days from each start's clock
    time to k steps later (0 where no earlier day is complete); ``scale(a)``: a factor per start
    on the change of the earlier day starting at index ``a`` (None: 1; a study's hook)."""
    per_day = int(round(DAY_S / dt))
    n = len(t_out)
    shape = np.zeros((len(starts), len(k)))
    count = np.zeros((len(starts), 1))
    for d in range(1, days + 1):  # the same clock interval on earlier days
        a = starts - d * per_day
        ok = (a >= 0)[:, None] & ((a[:, None] + k[None, :]) < n)
        a_c = np.clip(a, 0, n - 1)
        b_c = np.clip(a[:, None] + k[None, :], 0, n - 1)
        change = t_out[b_c] - t_out[a_c][:, None]
        if scale is not None:
            change = change * scale(a_c)[:, None]
        good = ok & np.isfinite(change)
        full = np.all(good, axis=1, keepdims=True)
        shape += np.where(full, np.where(good, change, 0.0), 0.0)
        count += full
    return np.where(count > 0, shape / np.maximum(count, 1), 0.0)


class ClearSkyTrend:
    """The ``clear-sky-trend`` outlook for a greenhouse at ``site`` (see the module doc).

    Settings are physical time scales, the same for every greenhouse (chosen on the Bleiswijk
    stretch 2009-11-04..24, outside the generality windows): ``index_window`` [s] of the
    clear-sky index, ``trend_window`` [s] of the level and trend lines, ``wind_window`` [s],
    ``trend_damping`` [s] e-folding time of the extrapolated trends, ``shape_days`` days of
    daily shape and its weight ``shape_weight`` [-].
    """

    name = "clear-sky-trend"
    MIN_CLEAR = 50.0
    """Clear-sky radiation [W m-2] below which a sample does not count in the index."""
    DEFAULT_INDEX = 0.5
    """Clear-sky index before any daylight was seen [-]."""

    def __init__(self, site: Site, index_window: float = 900.0, trend_window: float = 1800.0,
                 wind_window: float = 900.0, trend_damping: float = 900.0, shape_days: int = 3,
                 shape_weight: float = 0.5) -> None:
        self.site = site
        self.index_window, self.trend_window, self.wind_window = index_window, trend_window, wind_window
        self.trend_damping, self.shape_days, self.shape_weight = trend_damping, shape_days, shape_weight

    @classmethod
    def for_greenhouse(cls, gh: Greenhouse) -> ClearSkyTrend:
        if gh.site is None:
            raise ValueError(f"{gh.source}: the clear-sky-trend outlook needs [site] latitude and "
                             "longitude (the sun's position)")
        return cls(gh.site)

    def _clear(self, unix: np.ndarray) -> np.ndarray:
        t = unix.astype(np.int64).astype("datetime64[s]")
        return clear_sky_global(solar_position(t, self.site.latitude, self.site.longitude).cos_zenith)

    # -- radiation ----------------------------------------------------------------------------
    def clear_sky_index(self, i_glob: np.ndarray, unix: np.ndarray, dt: float) -> np.ndarray:
        """Causal clear-sky index at each index: sum of the measured over sum of the clear-sky
        radiation over the last ``index_window``, counting only samples whose clear sky is at
        least ``MIN_CLEAR``; carried from its last value when the window holds less than half
        its length at ``MIN_CLEAR`` (night, first weak light)."""
        clear = self._clear(unix)
        use = (clear >= self.MIN_CLEAR) & np.isfinite(i_glob)
        win = max(int(round(self.index_window / dt)), 1)
        s_meas, _ = _trailing_sums(np.where(use, i_glob, np.nan), win)
        s_clear, _ = _trailing_sums(np.where(use, clear, np.nan), win)
        enough = s_clear >= 0.5 * win * self.MIN_CLEAR
        k = forward_fill(np.where(enough, s_meas / np.where(enough, s_clear, 1.0), np.nan))
        return np.clip(np.where(np.isfinite(k), k, self.DEFAULT_INDEX), 0.0, 1.3)

    # -- the outlook ----------------------------------------------------------------------------
    def drivers_at(self, columns: Mapping[str, np.ndarray], time: np.ndarray, starts: np.ndarray,
                   horizon: int, dt: float) -> dict[str, np.ndarray]:
        """Columns (N, horizon) for the steps start + 1 … start + horizon of every start, from
        ``columns`` (full series on ``time``) read only up to each start."""
        starts = np.asarray(starts, dtype=int)
        unix = _unix(time)
        k = np.arange(1, horizon + 1)
        ahead = k * dt  # [s]
        out: dict[str, np.ndarray] = {}
        for name, values in columns.items():  # held columns
            out[name] = np.repeat(forward_fill(np.asarray(values, float))[starts][:, None], horizon, axis=1)
        if "i_glob" in columns:
            ig = np.asarray(columns["i_glob"], float)
            index = self.clear_sky_index(ig, unix, dt)
            future = unix[starts][:, None] + ahead[None, :]
            out["i_glob"] = index[starts][:, None] * self._clear(future.ravel()).reshape(future.shape)
        t_fc = None
        if "t_out" in columns:
            t_fc = self._temperature(np.asarray(columns["t_out"], float), starts, k, dt)
            out["t_out"] = t_fc
        if "rh_out" in columns and t_fc is not None:
            e = saturation_vapour_pressure(np.asarray(columns["t_out"], float)) \
                * np.asarray(columns["rh_out"], float) / 100.0
            level, slope = trailing_line(e, max(int(round(self.trend_window / dt)), 2))
            e_fc = level[starts][:, None] + slope[starts][:, None] * self._damped(k, dt)[None, :]
            rh = 100.0 * e_fc / saturation_vapour_pressure(t_fc)
            out["rh_out"] = np.clip(rh, 1.0, 100.0)
        if "wind" in columns:
            s, c = _trailing_sums(np.asarray(columns["wind"], float),
                                  max(int(round(self.wind_window / dt)), 1))
            mean = np.where(c > 0, s / np.where(c > 0, c, 1.0), np.nan)
            out["wind"] = np.repeat(mean[starts][:, None], horizon, axis=1)
        return out

    def _damped(self, k: np.ndarray, dt: float) -> np.ndarray:
        """Extrapolated steps of a trend damped with e-folding time ``trend_damping``:
        sum_{j<=k} exp(-j dt / tau) [samples]."""
        r = np.exp(-dt / self.trend_damping)
        return r * (1.0 - r ** k) / (1.0 - r)

    def _temperature(self, t_out: np.ndarray, starts: np.ndarray, k: np.ndarray,
                     dt: float) -> np.ndarray:
        level, slope = trailing_line(t_out, max(int(round(self.trend_window / dt)), 2))
        shape = daily_shape(t_out, starts, k, dt, self.shape_days)
        trend = slope[starts][:, None] * self._damped(k, dt)[None, :]
        return level[starts][:, None] + self.shape_weight * shape + trend

    def drivers(self, history: Mapping[str, np.ndarray], time: np.ndarray, horizon: int,
                dt: float) -> dict[str, np.ndarray]:
        """The :class:`~gateway.estimate.outlook.Outlook` call: the coming ``horizon`` steps
        after the last row of ``history``."""
        if horizon < 0:
            raise ValueError(f"horizon must be >= 0, got {horizon}")
        if horizon == 0:
            return {k: np.zeros(0) for k in history}
        n = len(time)
        if n == 0:
            return {k: np.full(horizon, np.nan) for k in history}
        out = self.drivers_at(history, time, np.array([n - 1]), horizon, dt)
        return {k: v[0] for k, v in out.items()}

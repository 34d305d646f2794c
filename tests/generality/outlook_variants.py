"""Variants of the weather outlook and of the outlook's error correction, for the study
tests/generality/outlook_study.py (issue 10: what a causal outlook could still gain).

Causal variants of ``clear-sky-trend``'s radiation (nothing after the start is read; checked by
tests/test_outlook_variants.py):

- :class:`IndexBlend`: the clear-sky index relaxed from its current value k_now toward a
  reference k_ref, the ratio of sums over the last ``ref_window`` (the recent days' cloudiness),
  with the lead time:  k(t + h) = k_ref + (k_now − k_ref) exp(−h / tau).  A convex combination
  of climatology and persistence (Yang 2019, "Making reference solar forecasts with
  climatology, persistence, and their optimal convex combination", Solar Energy 193, 981-985),
  with a fixed e-folding time instead of the optimal weight.
- :class:`OnlineBlend`: the same with Yang's weight estimated online, per lead time, as the
  least-squares slope of the index h steps later on the index now, over the pairs of the last
  ``memory`` whose later end is already measured (the mean-square-optimal convex weight when
  the index is stationary); the reference is the mean index of the same span.

Causal variants of its outside temperature (the ol candidates, docs/effects.md "The outlook's
drivers, one at a time"; neither passed its rule): :class:`ShapeVariant` with ``shape_by_index``
(each earlier day's change scaled by the ratio of the clear-sky indices now and then, Dai,
Trenberth & Karl 1999) or ``shape_memory`` (the daily shape's weight per lead time learnt online
from matured pairs, Yang 2019's optimal convex weight).

Not causal, diagnostics only (what a perfect weather forecast would be worth):

- :class:`Measured`: the named columns replaced by what was measured later;
- :class:`HourlyCloudiness`: radiation = the clear sky × the clear-sky index measured over each
  clock hour (a perfect hourly cloudiness forecast, as a weather service could at best send).

:func:`correct_with` runs gateway/estimate/correction.py's ``Corrector`` with extra feature
columns appended to φ (e.g. a second daily harmonic, the last error of the measured-weather
forecast) on a scored replay.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from gateway.estimate import correction
from gateway.estimate.clear_sky_trend import (
    ClearSkyTrend,
    _trailing_sums,
    _unix,
    daily_shape,
    forward_fill,
    trailing_line,
)
from gateway.greenhouse import Site


class IndexBlend(ClearSkyTrend):
    """``clear-sky-trend`` with the index relaxed toward its ``ref_window`` [s] ratio of sums
    with e-folding time ``tau`` [s] of lead time (module doc)."""

    name = "index-blend"

    def __init__(self, site: Site, ref_window: float = 86400.0, tau: float = 3600.0) -> None:
        super().__init__(site)
        self.ref_window, self.tau = ref_window, tau

    def reference_index(self, i_glob: np.ndarray, unix: np.ndarray, dt: float) -> np.ndarray:
        """Ratio of sums (measured / clear sky) over the last ``ref_window`` of the samples
        whose clear sky is at least ``MIN_CLEAR``; the current index until half an hour of
        such samples was seen."""
        clear = self._clear(unix)
        use = (clear >= self.MIN_CLEAR) & np.isfinite(i_glob)
        win = max(int(round(self.ref_window / dt)), 1)
        s_meas, _ = _trailing_sums(np.where(use, i_glob, np.nan), win)
        s_clear, n = _trailing_sums(np.where(use, clear, np.nan), win)
        enough = n * dt >= 1800.0
        k = forward_fill(np.where(enough, s_meas / np.where(enough, s_clear, 1.0), np.nan))
        now = self.clear_sky_index(i_glob, unix, dt)
        return np.clip(np.where(np.isfinite(k), k, now), 0.0, 1.3)

    def index_ahead(self, i_glob: np.ndarray, unix: np.ndarray, starts: np.ndarray,
                    horizon: int, dt: float) -> np.ndarray:
        """(N, horizon) clear-sky index at the steps start + 1 … start + horizon."""
        now = self.clear_sky_index(i_glob, unix, dt)[starts][:, None]
        ref = self.reference_index(i_glob, unix, dt)[starts][:, None]
        w = np.exp(-np.arange(1, horizon + 1) * dt / self.tau)[None, :]
        return ref + (now - ref) * w

    def drivers_at(self, columns: Mapping[str, np.ndarray], time: np.ndarray,
                   starts: np.ndarray, horizon: int, dt: float) -> dict[str, np.ndarray]:
        out = super().drivers_at(columns, time, starts, horizon, dt)
        if "i_glob" in columns:
            starts = np.asarray(starts, dtype=int)
            unix = _unix(time)
            k = self.index_ahead(np.asarray(columns["i_glob"], float), unix, starts, horizon, dt)
            future = unix[starts][:, None] + np.arange(1, horizon + 1)[None, :] * dt
            out["i_glob"] = k * self._clear(future.ravel()).reshape(future.shape)
        return out


class OnlineBlend(IndexBlend):
    """:class:`IndexBlend` with the weight of each lead time estimated online (module doc)
    over the last ``memory`` [s]; at least ``min_pairs`` pairs, else persistence (weight 1)."""

    name = "online-blend"

    def __init__(self, site: Site, memory: float = 3 * 86400.0, min_pairs: int = 24) -> None:
        super().__init__(site, ref_window=memory)
        self.min_pairs = min_pairs

    def weights(self, i_glob: np.ndarray, unix: np.ndarray, horizon: int,
                dt: float) -> np.ndarray:
        """(T, horizon) weight of the current index at each index and lead time, from the
        pairs (s, s + h) with s + h at or before that index."""
        clear = self._clear(unix)
        strong = (clear >= self.MIN_CLEAR) & np.isfinite(i_glob)
        k_inst = np.where(strong, i_glob / np.where(strong, clear, 1.0), np.nan)
        k_now = np.where(strong, self.clear_sky_index(i_glob, unix, dt), np.nan)
        win = max(int(round(self.ref_window / dt)), 1)
        n = len(i_glob)
        out = np.ones((n, horizon))
        for h in range(1, min(horizon, n - 1) + 1):
            x, y = np.full(n, np.nan), np.full(n, np.nan)
            x[h:], y[h:] = k_now[:-h], k_inst[h:]  # stamped at the later end: known there
            ok = np.isfinite(x) & np.isfinite(y)
            x, y = np.where(ok, x, np.nan), np.where(ok, y, np.nan)
            sx, c = _trailing_sums(x, win)
            sy, _ = _trailing_sums(y, win)
            sxx, _ = _trailing_sums(x * x, win)
            sxy, _ = _trailing_sums(x * y, win)
            c1 = np.maximum(c, 1.0)
            var, cov = sxx - sx * sx / c1, sxy - sx * sy / c1
            good = (c >= self.min_pairs) & (var > 1e-9)
            slope = np.where(good, cov / np.where(good, var, 1.0), np.nan)
            out[:, h - 1] = np.clip(np.where(np.isfinite(slope), slope, 1.0), 0.0, 1.0)
        return out

    def index_ahead(self, i_glob: np.ndarray, unix: np.ndarray, starts: np.ndarray,
                    horizon: int, dt: float) -> np.ndarray:
        now = self.clear_sky_index(i_glob, unix, dt)[starts][:, None]
        ref = self.reference_index(i_glob, unix, dt)[starts][:, None]
        return ref + (now - ref) * self.weights(i_glob, unix, horizon, dt)[starts]


SKY_SCALE_BOUNDS = (1.0 / 3.0, 3.0)
"""Bounds of ``sky_scale`` [-]: a near-zero index (deep overcast, first light) must not wipe or
blow up the daily shape."""


def sky_scale(index_now: np.ndarray, index_then: np.ndarray) -> np.ndarray:
    """How much larger the coming change of the outside temperature is than an earlier day's over
    the same clock interval: the ratio of the clear-sky indices now and then, bounded by
    ``SKY_SCALE_BOUNDS`` (1 where it is undefined: an index missing, or zero then). The
    diurnal range of the air temperature grows with the clearness of the sky (sun by day,
    long-wave loss by night; clouds are the strongest damper of it: Dai, Trenberth & Karl 1999,
    "Effects of clouds, soil moisture, precipitation, and water vapor on diurnal temperature
    range", J. Climate 12, 2451-2473), so the change is taken proportional to the index."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.asarray(index_now, float) / np.asarray(index_then, float)
    return np.where(np.isfinite(r), np.clip(r, *SKY_SCALE_BOUNDS), 1.0)


class ShapeVariant(ClearSkyTrend):
    """``clear-sky-trend`` with the outside temperature's daily shape scaled by the sky
    (``shape_by_index``) and/or its weight learnt online over ``shape_memory`` [s] (module doc).
    One code path: ``drivers`` (live) is ``drivers_at`` for the last start."""

    name = "shape-variant"
    MIN_SHAPE_PAIRS = 24
    """Matured (start, lead) pairs before an online shape weight is used (two hours at 5 min)."""

    def __init__(self, site: Site, shape_by_index: bool = False,
                 shape_memory: float | None = None, **settings: float) -> None:
        super().__init__(site, **settings)  # ClearSkyTrend's settings (its defaults by default)
        self.shape_by_index, self.shape_memory = shape_by_index, shape_memory
        self._index: np.ndarray | None = None

    def drivers_at(self, columns: Mapping[str, np.ndarray], time: np.ndarray,
                   starts: np.ndarray, horizon: int, dt: float) -> dict[str, np.ndarray]:
        # the clear-sky index of this call's series, for _temperature (which the base calls)
        self._index = None
        if self.shape_by_index and "i_glob" in columns:
            self._index = self.clear_sky_index(np.asarray(columns["i_glob"], float), _unix(time), dt)
        try:
            return super().drivers_at(columns, time, starts, horizon, dt)
        finally:
            self._index = None

    def _temperature(self, t_out: np.ndarray, starts: np.ndarray, k: np.ndarray,
                     dt: float) -> np.ndarray:
        """Level + weight × the mean change of the earlier days over the same clock interval
        (each scaled by ``sky_scale`` when ``index``, the clear-sky index, is given) + the damped
        trend; the weight is ``shape_weight``, or learnt online (``shape_weights``)."""
        index = self._index
        level, slope = trailing_line(t_out, max(int(round(self.trend_window / dt)), 2))
        trend = slope[:, None] * self._damped(k, dt)[None, :]
        if self.shape_memory is None:
            shape = self._shape(t_out, starts, k, dt, index)
            return level[starts][:, None] + self.shape_weight * shape + trend[starts]
        every = np.arange(len(t_out))
        shape = self._shape(t_out, every, k, dt, index)
        weight = self.shape_weights(t_out, level[:, None] + trend, shape, k, dt)
        return (level[:, None] + weight * shape + trend)[starts]

    def _shape(self, t_out: np.ndarray, starts: np.ndarray, k: np.ndarray, dt: float,
               index: np.ndarray | None) -> np.ndarray:
        """(N, len(k)) mean change of the last ``shape_days`` days from the start's clock time
        to k steps later (0 where no earlier day is complete)."""
        scale = None if index is None else (lambda a: sky_scale(index[starts], index[a]))
        return daily_shape(t_out, starts, k, dt, self.shape_days, scale)

    def shape_weights(self, t_out: np.ndarray, base: np.ndarray, shape: np.ndarray,
                      k: np.ndarray, dt: float) -> np.ndarray:
        """(T, len(k)) weight of the daily shape at each index and lead time: the least-squares
        slope through the origin of what the shape had to add, T[s + h] − ``base``[s, h] (level
        and damped trend), on the shape, over the pairs of the last ``shape_memory`` whose later
        end is at or before the index (known there); bounded to [0, 1]; ``shape_weight`` until
        ``MIN_SHAPE_PAIRS`` pairs. The mean-square-optimal convex weight of a "climatology"
        (here the daily cycle) against persistence (Yang 2019, Solar Energy 193, 981-985)."""
        n = len(t_out)
        win = max(int(round(self.shape_memory / dt)), 1)
        out = np.full((n, len(k)), self.shape_weight)
        for j, h in enumerate(k):
            if h >= n:
                continue
            x, y = np.full(n, np.nan), np.full(n, np.nan)
            x[h:] = shape[:-h, j]  # stamped at the later end s + h: known from there on
            y[h:] = t_out[h:] - base[:-h, j]
            ok = np.isfinite(x) & np.isfinite(y) & (x != 0.0)
            sxy, c = _trailing_sums(np.where(ok, x * y, np.nan), win)
            sxx, _ = _trailing_sums(np.where(ok, x * x, np.nan), win)
            good = (c >= self.MIN_SHAPE_PAIRS) & (sxx > 0)
            w = np.clip(sxy / np.where(good, sxx, 1.0), 0.0, 1.0)
            out[:, j] = np.where(good, w, self.shape_weight)
        return out


class Measured:
    """NOT causal: ``base``'s outlook with ``columns`` replaced by the measured future."""

    def __init__(self, base, columns: tuple[str, ...]) -> None:
        self.base, self.columns = base, columns
        self.name = "measured " + ", ".join(columns)

    def drivers_at(self, columns: Mapping[str, np.ndarray], time: np.ndarray,
                   starts: np.ndarray, horizon: int, dt: float) -> dict[str, np.ndarray]:
        out = self.base.drivers_at(columns, time, starts, horizon, dt)
        n = len(time)
        rows = np.clip(np.asarray(starts, int)[:, None] + np.arange(1, horizon + 1)[None, :], 0, n - 1)
        for c in self.columns:
            if c in columns:
                out[c] = np.asarray(columns[c], float)[rows]
        return out


class HourlyCloudiness(ClearSkyTrend):
    """NOT causal: radiation = clear sky × the index measured over each clock hour."""

    name = "hourly-cloudiness"

    def drivers_at(self, columns: Mapping[str, np.ndarray], time: np.ndarray,
                   starts: np.ndarray, horizon: int, dt: float) -> dict[str, np.ndarray]:
        out = super().drivers_at(columns, time, starts, horizon, dt)
        unix = _unix(time)
        clear = self._clear(unix)
        hour = (unix // 3600.0).astype(np.int64)
        hour -= hour[0]
        i_glob = np.nan_to_num(np.asarray(columns["i_glob"], float))
        s_meas, s_clear = np.bincount(hour, weights=i_glob), np.bincount(hour, weights=clear)
        k = np.clip(np.where(s_clear > 1.0, s_meas / np.maximum(s_clear, 1e-9), 0.0), 0.0, 1.5)
        n = len(unix)
        rows = np.clip(np.asarray(starts, int)[:, None] + np.arange(1, horizon + 1)[None, :], 0, n - 1)
        out["i_glob"] = k[hour[rows]] * clear[rows]
        return out


def forecasts_by_steps(res, suffix: str) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray],
                                                  dict[int, np.ndarray]]:
    """The scored replay's ``combined{suffix}`` and ``arx{suffix}`` forecasts as series on its
    time axis by lead time in steps (NaN where no forecast starts), and the start indices by lead
    time in minutes."""
    n = len(res.measured)
    comb: dict[int, np.ndarray] = {}
    arx: dict[int, np.ndarray] = {}
    starts: dict[int, np.ndarray] = {}
    for minutes, f in res.horizons.items():
        steps = int(round(minutes * 60.0 / res.dt))
        starts[minutes] = f["target"] - steps
        comb[steps], arx[steps] = np.full(n, np.nan), np.full(n, np.nan)
        comb[steps][starts[minutes]] = f[f"combined{suffix}"]
        arx[steps][starts[minutes]] = f[f"arx{suffix}"]
    return comb, arx, starts


def ahead_by_steps(res, suffix: str, starts: Mapping[int, np.ndarray]) -> dict[int, dict[str, np.ndarray]]:
    """The correction's change of the forecast's own drivers over each horizon (replay's, by lead
    time in steps, on the replay's time axis), for ``correction.correct_series``'s ``ahead``."""
    from gateway.estimate import replay_forecasts as rf

    out = {}
    for minutes, s in starts.items():
        steps = int(round(minutes * 60.0 / res.dt))
        out[steps] = rf._ahead_change(res, s, steps, suffix)
    return out


def correct_with(res, extra: Mapping[int, np.ndarray], suffix: str) -> None:
    """Replace ``corrected{suffix}`` of the scored replay ``res`` by the correction with the
    columns ``extra[steps]`` (T, m) (their values at each start, NaN counted as 0) appended to
    φ; ``extra`` empty gives gateway/estimate/correction.py's own figures."""
    n = len(res.measured)
    comb, arx, starts = forecasts_by_steps(res, suffix)
    ahead = ahead_by_steps(res, suffix, starts)
    m = next(iter(extra.values())).shape[1] if extra else 0
    base_features, base_names = correction.features, correction.FEATURES
    now: dict[str, np.ndarray] = {"extra": np.zeros(m)}
    correction.features = lambda *a: np.concatenate([base_features(*a), now["extra"]])  # type: ignore[assignment]
    correction.FEATURES = (*base_names, *(f"extra {i}" for i in range(m)))
    try:
        corr = correction.Corrector(list(comb), res.dt)
        out = {h: np.full(n, np.nan) for h in comb}
        cols = {"i_glob": res.x["i_glob"], "t_out": res.x["t_out"],
                "hour": correction.hour_of_day(res.time)}
        for t in range(n):
            corr.observe(float(res.measured[t]))
            row = {k: float(v[t]) for k, v in cols.items()}
            for h, f in comb.items():
                if math.isfinite(f[t]):
                    now["extra"] = np.nan_to_num(extra[h][t]) if m else np.zeros(0)
                    row_h = row | {k: float(v[t]) for k, v in ahead[h].items()}
                    out[h][t] = corr.correct(h, float(f[t]), float(res.measured[t]), row_h,
                                             float(arx[h][t]))
            corr.add()
    finally:
        correction.features, correction.FEATURES = base_features, base_names  # type: ignore[assignment]
    for minutes, f in res.horizons.items():
        f[f"corrected{suffix}"] = out[int(round(minutes * 60.0 / res.dt))][starts[minutes]]


def tuning_replays(folder) -> list:
    """(file stem, replay) of the tuning generators' replays kept in ``folder`` (``forecasts.py
    --keep``), forecasts scored with the current code; the held-out generator's are skipped."""
    import pickle
    from pathlib import Path

    from gateway.estimate import replay as rp
    from tests.generality.generators import HELD_OUT

    out = []
    for f in sorted(Path(folder).glob("*.pkl")):
        if f.stem.split("-", 1)[0] in HELD_OUT:
            continue
        res = pickle.loads(f.read_bytes())
        rp.score_forecasts(res, rp.steps_of(rp.HORIZONS, res.dt))
        out.append((f.stem, res))
    return out

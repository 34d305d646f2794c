"""The outlook study's variants (tests/generality/outlook_variants.py): the causal ones read
nothing after the start, blend between the current and the reference index as documented, and
the diagnostics that may read the future do."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.estimate.clear_sky_trend import ClearSkyTrend, _unix, trailing_line
from gateway.greenhouse import Site
from gateway.model.solar import clear_sky_global, solar_position
from tests.generality.outlook_variants import (
    HourlyCloudiness,
    IndexBlend,
    Measured,
    OnlineBlend,
    ShapeVariant,
    sky_scale,
)

SITE = Site(52.03, 4.53)
DT = 300.0


def _weather(days: int = 5, seed: int = 3) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    time = np.datetime64("2009-11-01T00:00", "s") + np.arange(days * 288) * np.timedelta64(300, "s")
    clear = clear_sky_global(solar_position(time, SITE.latitude, SITE.longitude).cos_zenith)
    rng = np.random.default_rng(seed)
    index = np.clip(0.5 + 0.3 * np.sin(np.arange(len(time)) / 7.0) + 0.1 * rng.normal(size=len(time)),
                    0.05, 1.1)
    hours = (time - time.astype("datetime64[D]")).astype(float) / 3600.0
    t_out = 6.0 + 3.0 * np.sin(2 * np.pi * (hours - 9.0) / 24.0)
    return time, {"i_glob": index * clear, "t_out": t_out, "rh_out": np.full(len(time), 80.0),
                  "wind": np.full(len(time), 3.0), "t_in": t_out + 2.0}


def _days(n_days: int) -> np.ndarray:
    return np.datetime64("2009-11-01T00:00", "s") + np.arange(n_days * 288) * np.timedelta64(300, "s")


def _clear(time: np.ndarray) -> np.ndarray:
    return clear_sky_global(solar_position(time, SITE.latitude, SITE.longitude).cos_zenith)


def test_the_causal_variants_read_nothing_after_the_start():
    time, w = _weather()
    starts = np.array([3 * 288 + 130, 4 * 288 + 140])  # late morning on days 4 and 5
    changed = {k: v.copy() for k, v in w.items()}
    for s in starts:
        for v in changed.values():
            v[s + 1:] *= 1.7
        for variant in (IndexBlend(SITE), IndexBlend(SITE, 3 * 86400.0, 1800.0), OnlineBlend(SITE)):
            a = variant.drivers_at(w, time, np.array([s]), 12, DT)
            b = variant.drivers_at(changed, time, np.array([s]), 12, DT)
            for k in a:
                np.testing.assert_array_equal(a[k], b[k], err_msg=f"{variant.name} {k}")
        changed = {k: v.copy() for k, v in w.items()}
    # the diagnostics do read the future (that is what they are for)
    for diagnostic in (Measured(ClearSkyTrend(SITE), ("i_glob",)), HourlyCloudiness(SITE)):
        for v in changed.values():
            v[starts[0] + 1:] *= 1.7
        a = diagnostic.drivers_at(w, time, starts[:1], 12, DT)["i_glob"]
        b = diagnostic.drivers_at(changed, time, starts[:1], 12, DT)["i_glob"]
        assert not np.allclose(a, b)
        changed = {k: v.copy() for k, v in w.items()}


def test_the_blend_goes_from_the_current_index_to_the_reference():
    time, w = _weather()
    unix = _unix(time)
    blend = IndexBlend(SITE, 86400.0, 3600.0)
    s = np.array([3 * 288 + 130])
    now = blend.clear_sky_index(w["i_glob"], unix, DT)[s]
    ref = blend.reference_index(w["i_glob"], unix, DT)[s]
    k = blend.index_ahead(w["i_glob"], unix, s, 12, DT)[0]
    expected = ref + (now - ref) * np.exp(-np.arange(1, 13) * DT / 3600.0)
    np.testing.assert_allclose(k, expected)
    assert abs(now[0] - ref[0]) > 0.01  # the test is not trivial
    # a very long e-folding time is clear-sky-trend's index persistence
    a = IndexBlend(SITE, 86400.0, 1e15).drivers_at(w, time, s, 12, DT)["i_glob"]
    b = ClearSkyTrend(SITE).drivers_at(w, time, s, 12, DT)["i_glob"]
    np.testing.assert_allclose(a, b, rtol=1e-6)
    # online weights: in [0, 1] and falling with lead time on a mean-reverting index
    wts = OnlineBlend(SITE).weights(w["i_glob"], unix, 12, DT)[s[0]]
    assert np.all((wts >= 0.0) & (wts <= 1.0)) and wts[0] > wts[-1]


def assert_live_is_batch(outlook, starts: tuple[int, ...]) -> None:
    """The single-start call on the history up to each start equals the batch call."""
    time, w = _weather()
    for s in starts:
        live = outlook.drivers({k: v[: s + 1] for k, v in w.items()}, time[: s + 1], 12, DT)
        batch = outlook.drivers_at(w, time, np.array([s]), 12, DT)
        for k in w:
            np.testing.assert_array_equal(live[k], batch[k][0], err_msg=f"{k} at {s}")


def test_the_blends_live_call_is_its_replay_block():
    """The ol candidate ``index-blend`` (tests/generality/outlook_costs.py): the live gateway's
    single-start call on the history up to now equals replay's batch call for that start."""
    assert_live_is_batch(IndexBlend(SITE, 86400.0, 3600.0), (3 * 288 + 40, 3 * 288 + 130, 4 * 288 + 150))


def test_the_daily_shape_scaled_by_the_sky_follows_a_duller_day():
    """``shape_by_index`` (a candidate, off by default): an outside temperature whose daily swing
    is proportional to each day's clear-sky index (Dai et al. 1999: clouds damp the diurnal
    range) is forecast exactly from earlier, clearer days; the unscaled shape overshoots."""
    time = _days(4)
    clear = _clear(time)
    day = np.arange(len(time)) // 288
    k_day = np.array([0.8, 0.9, 0.7, 0.4])[day]  # the last day is the dullest
    hours = (time - time.astype("datetime64[D]")).astype(float) / 3600.0
    t_out = 5.0 + 8.0 * k_day * np.sin(2 * np.pi * (hours - 9.0) / 24.0)
    w = {"i_glob": k_day * clear, "t_out": t_out}
    s = 3 * 288 + int(np.argmax(clear[:288])) - 18  # 90 min before noon on the last day
    kw = {"shape_weight": 1.0, "trend_damping": 1e-9}  # the shape alone beside the level
    scaled = ShapeVariant(SITE, shape_by_index=True, **kw).drivers_at(w, time, np.array([s]), 12, DT)
    plain = ClearSkyTrend(SITE, **kw).drivers_at(w, time, np.array([s]), 12, DT)
    level = trailing_line(t_out, 6)[0][s]
    truth = level + t_out[s + 1: s + 13] - t_out[s]
    np.testing.assert_allclose(scaled["t_out"][0], truth, atol=1e-9)
    assert np.all(plain["t_out"][0][1:] - truth[1:] > 0.1)  # 0.8 / 0.4 too steep a rise
    assert not hasattr(ClearSkyTrend(SITE), "shape_by_index")  # not in the gateway's outlook


def test_sky_scale_is_the_bounded_ratio_of_the_indices():
    np.testing.assert_allclose(sky_scale(np.array([0.4, 0.9, 0.01, 0.5, 0.5]),
                                         np.array([0.8, 0.3, 0.9, 0.0, np.nan])),
                               [0.5, 3.0, 1.0 / 3.0, 1.0, 1.0])  # no ratio of a zero index


@pytest.mark.parametrize("settings", [{"shape_by_index": True}, {"shape_memory": 2 * 86400.0},
                                      {"shape_by_index": True, "shape_memory": 2 * 86400.0}])
def test_a_candidates_live_call_is_its_replay_block(settings):
    """One code path: the live gateway's single-start call on the history up to now equals
    replay's batch call for that start on the whole series (which also reads nothing later)."""
    assert_live_is_batch(ShapeVariant(SITE, **settings), (3 * 288 + 40, 3 * 288 + 130, 3 * 288 + 200))


def test_the_online_shape_weight_is_one_on_a_daily_cycle_and_none_on_a_random_walk():
    """``shape_memory`` (a candidate, off by default): the weight of the daily shape learnt from
    matured pairs is the mean-square-optimal one (Yang 2019): ~1 where the outside temperature
    repeats its day exactly, ~0 where it has no daily cycle (a random walk), ``shape_weight``
    before enough pairs."""
    time = _days(5)
    k = np.arange(1, 13)
    hours = (time - time.astype("datetime64[D]")).astype(float) / 3600.0
    cycle = 6.0 + 4.0 * np.sin(2 * np.pi * (hours - 9.0) / 24.0)
    walk = 6.0 + np.cumsum(np.random.default_rng(5).normal(0.0, 0.1, len(time)))
    for t_out, lo, hi in ((cycle, 0.9, 1.0), (walk, 0.0, 0.25)):
        cst = ShapeVariant(SITE, trend_damping=1e-9, shape_memory=86400.0)
        level = trailing_line(t_out, 6)[0]
        every = np.arange(len(time))
        shape = cst._shape(t_out, every, k, DT, None)
        w = cst.shape_weights(t_out, np.repeat(level[:, None], 12, axis=1), shape, k, DT)
        late = w[4 * 288:]  # two full days of shape and a day of pairs behind
        assert lo <= late.mean() <= hi, (lo, late.mean(), hi)
        assert np.all((w >= 0.0) & (w <= 1.0))
        np.testing.assert_array_equal(w[: 288 + 12], 0.5)  # no shape yet: the fixed weight

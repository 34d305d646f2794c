"""The live gateway's forecast drivers are replay's: one block made now (gateway/estimate/horizon.py
``live_block``, what gateway/service/pipeline.py forecasts with) equals the block replay's
``outlook_drivers`` lays out for the same start, derived drivers included; the cloud fraction is
the estimator's at the start, held over the horizon (not read again from the block alone, which
would put the prior 0.6 on every night)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.estimate.horizon import live_block, outlook_drivers
from gateway.estimate.outlook import make_outlook
from gateway.greenhouse import load_greenhouse
from gateway.model import sky
from gateway.model.drivers import prepare_drivers
from gateway.series import Series
from gateway.service.minutes import KIT_COLUMNS

GH = load_greenhouse("biskra-prototype")
DT = 60.0
H = 60


@pytest.fixture(scope="module")
def week() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Three days of kit columns at 1-min steps at the greenhouse's site: a clear first day, a
    half-cloudy second one and a clear third, so the carried night cloud is neither 0 nor 0.6."""
    assert GH.site is not None
    n = 3 * 1440
    time = np.datetime64("2021-04-10T00:00:00") + np.arange(n) * np.timedelta64(60, "s")
    day = np.arange(n) // 1440
    clear = sky.clear_sky(time, GH.site.latitude, GH.site.longitude)
    i_glob = clear * np.where(day == 1, 0.45, 0.95)
    hours = np.arange(n) / 60.0
    t_out = 16.0 + 7.0 * np.sin(2 * np.pi * (hours - 9.0) / 24.0)
    cols = {"t_in": t_out + 3.0 + 0.004 * i_glob, "rh_in": np.full(n, 65.0), "t_out": t_out,
            "rh_out": 50.0 - 1.5 * (t_out - 16.0), "i_glob": i_glob,
            "wind": 2.0 + np.sin(hours / 5.0)}
    return time, cols


@pytest.mark.parametrize("start_hour", [23.0, 26.5, 60.0])  # evening, night, midday of day 3
def test_a_live_block_is_the_replay_block_of_its_start(week, start_hour: float) -> None:
    time, cols = week
    x = prepare_drivers(Series(time, DT, cols), GH)
    s = int(start_hour * 60)
    outlook = make_outlook("clear-sky-trend", GH)
    kit = [c for c in KIT_COLUMNS if c in cols]
    blocks = outlook_drivers(outlook, x, kit, time, DT, GH, np.array([s]), H)
    live = live_block(outlook, {c: cols[c][: s + 1] for c in kit}, time[: s + 1], H, DT, GH,
                      float(x["cloud"][s]))
    assert np.all(live["cloud"] == x["cloud"][s])  # the estimator's cloud, held
    for name, v in live.items():
        assert v.shape == (H,), name
        np.testing.assert_allclose(v, blocks.x[name][:H], rtol=1e-12, atol=1e-12, err_msg=name)


def test_the_held_cloud_is_not_the_prior_at_night(week) -> None:
    """The bug this holds off: a night block read alone gives the prior cloud on every row."""
    time, cols = week
    x = prepare_drivers(Series(time, DT, cols), GH)
    s = 26 * 60  # 02:00 after the half-cloudy day
    alone = prepare_drivers(Series(time[s : s + H], DT, {c: v[s : s + H] for c, v in cols.items()}),
                            GH)
    assert np.all(alone["cloud"] == sky.DEFAULT_CLOUD)
    assert abs(x["cloud"][s] - sky.DEFAULT_CLOUD) > 0.05
    live = live_block(make_outlook("clear-sky-trend", GH),
                      {c: v[: s + 1] for c, v in cols.items()}, time[: s + 1], H, DT, GH,
                      float(x["cloud"][s]))
    np.testing.assert_allclose(live["t_sky"], sky.sky_temperature(live["t_out"], live["rh_out"],
                                                                   x["cloud"][s]))


def test_a_negative_offset_reads_the_same_live_and_in_replay() -> None:
    """A pyranometer's negative offset (the kit CSV accepts down to -10 W m-2) counts as 0 in
    the live outlook as in replay's (gateway/model/solar.py ``measured_global``): data stamped at
    the end of its averaging interval lags the computed sun, so the offset is still read in the
    first quarter-hours of strong clear sky, where the clear-sky index counts it."""
    assert GH.site is not None
    n = 2 * 1440
    time = np.datetime64("2021-04-10T00:00:00") + np.arange(n) * np.timedelta64(60, "s")
    lagged = sky.clear_sky(time - np.timedelta64(40, "m"), GH.site.latitude, GH.site.longitude)
    i_glob = np.where(lagged > 1.0, 0.9 * lagged, -6.0)
    hours = np.arange(n) / 60.0
    t_out = 16.0 + 7.0 * np.sin(2 * np.pi * (hours - 9.0) / 24.0)
    cols = {"t_in": t_out + 3.0, "rh_in": np.full(n, 65.0), "t_out": t_out,
            "rh_out": np.full(n, 50.0), "i_glob": i_glob, "wind": np.full(n, 2.0)}
    clear = sky.clear_sky(time, GH.site.latitude, GH.site.longitude)
    s = 1440 + int(np.argmax((clear[1440:] >= 50.0) & (i_glob[1440:] > 0.0)))  # day 2's first light read
    assert np.any(i_glob[s - 15 : s] < 0.0) and np.all(clear[s - 15 : s + 1] >= 30.0)
    x = prepare_drivers(Series(time, DT, cols), GH)
    outlook = make_outlook("clear-sky-trend", GH)
    kit = list(cols)
    blocks = outlook_drivers(outlook, x, kit, time, DT, GH, np.array([s]), H)
    live = live_block(outlook, {c: cols[c][: s + 1] for c in kit}, time[: s + 1], H, DT, GH,
                      float(x["cloud"][s]))
    assert np.all(live["i_glob"] >= 0.0)
    for name, v in live.items():
        np.testing.assert_allclose(v, blocks.x[name][:H], rtol=1e-12, atol=1e-12, err_msg=name)

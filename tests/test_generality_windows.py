"""The generality study's weather windows: real Bleiswijk stretches and the summer made from them."""

from __future__ import annotations

import numpy as np

from gateway.model import solar
from tests.generality.windows import ALMERIA, BLEISWIJK, load_window


def test_bleiswijk_windows_are_real_weather_at_their_site() -> None:
    for name in ("autumn", "winter"):
        w = load_window(name)
        assert len(w.time) == 14 * 1440 and (w.latitude, w.longitude) == BLEISWIJK
        k = solar.clear_sky_index(w.i_glob, w.time, w.latitude, w.longitude, min_clear_sky=250.0)
        # measured radiation against this site's clear sky: cloudy Dutch days, never far above 1
        # where the sun is high enough for the file's half-hour lag not to matter
        assert 0.2 < np.nanmean(k) < 0.8 and np.nanpercentile(k, 99) < 1.3


def test_summer_is_a_sunny_warm_june_at_almeria() -> None:
    autumn, summer = load_window("autumn"), load_window("summer")
    assert (summer.latitude, summer.longitude) == ALMERIA
    assert str(summer.time[0]).startswith("2009-06-10")
    clear = solar.clear_sky_global(solar.solar_position(summer.time, *ALMERIA).cos_zenith)
    assert np.all(summer.i_glob <= 1.2 * clear + 1e-9)  # no sun before sunrise or after sunset
    daily_mj = summer.i_glob.sum() * 60 / 1e6 / 14
    assert 20 < daily_mj < 32  # Almería June: 25–30 MJ m-2 d-1 on clear days
    assert 20 < summer.t_out.mean() < 28 and summer.t_out.max() > 30
    assert np.all(summer.rh_out <= 100.0)
    # the day-to-day weather sequence is the autumn's: warmer days stay warmer
    daily = lambda x: x.reshape(14, 1440).mean(axis=1)  # noqa: E731
    assert np.corrcoef(daily(autumn.t_out), daily(summer.t_out))[0, 1] > 0.99

"""Sky temperature from humidity and cloudiness (gateway/model/sky.py), against published forms
and the measured sky of the Bleiswijk weather file."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gateway.greenhouse import Site, load_greenhouse
from gateway.model import psychrometrics as psy
from gateway.model import sky, solar
from gateway.model.drivers import prepare_drivers
from gateway.series import Series
from training.weather import load_bleiswijk

SIGMA = 5.670374419e-8
BLEISWIJK = (52.03, 4.53)


@pytest.mark.parametrize(("t", "e"), [(-5.0, 0.3), (10.0, 1.0), (25.0, 2.5)])
def test_brutsaert_in_hpa_equals_campbell_norman_kpa_form(t, e):
    # Brutsaert (1975) eq. 11: 1.24 (e/T)^(1/7), e in mb; Campbell & Norman (1998) eq. 10.11
    # print the same law for e in kPa as 1.72 (e/T)^(1/7).
    got = sky.clear_sky_emissivity(t, e)
    assert got == pytest.approx(1.72 * (e / (t + 273.15)) ** (1 / 7), rel=2e-3)


@pytest.mark.parametrize("t", [-10.0, 5.0, 30.0])
def test_swinbank_fallback_is_the_published_emission(t):
    # Swinbank (1963): downward long wave 5.31e-13 T^6 W m-2 under clear skies, quoted as the
    # emissivity 9.2e-6 T^2 (e.g. Flerchinger et al. 2009, table 1): 2 % apart with today's σ
    t_k = t + 273.15
    eps = sky.clear_sky_emissivity(t)
    assert eps == pytest.approx(9.2e-6 * t_k**2)
    assert eps * SIGMA * t_k**4 == pytest.approx(5.31e-13 * t_k**6, rel=2.5e-2)
    assert sky.clear_sky_emissivity(t, np.nan) == pytest.approx(eps)  # missing humidity


def test_kasten_czeplak_inverse():
    # Kasten & Czeplak (1980): G/G_clear = 1 - 0.75 (N/8)^3.4; overcast 0.25, 4 oktas 0.929
    assert sky.cloud_fraction_from_index(0.25) == pytest.approx(1.0)
    assert sky.cloud_fraction_from_index(0.1) == pytest.approx(1.0)
    assert sky.cloud_fraction_from_index(1.0) == pytest.approx(0.0)
    assert sky.cloud_fraction_from_index(1.3) == pytest.approx(0.0)
    assert sky.cloud_fraction_from_index(1 - 0.75 * 0.5**3.4) == pytest.approx(0.5)


def test_unsworth_monteith_blend():
    # Unsworth & Monteith (1975): eps = (1 - 0.84 c) eps_clear + 0.84 c
    assert sky.sky_emissivity(0.7, 0.0) == pytest.approx(0.7)
    assert sky.sky_emissivity(0.7, 1.0) == pytest.approx(0.84 + 0.16 * 0.7)
    t_sky = sky.sky_temperature(10.0, 80.0, 1.0)
    assert t_sky < 10.0 and t_sky > sky.sky_temperature(10.0, 80.0, 0.0) + 8.0


def test_measured_bleiswijk_sky_is_followed():
    """51 days of the measured apparent sky temperature (GreenLight weather file): the new sky
    halves the error of III.13 (T_out alone) and has almost no bias."""
    w = load_bleiswijk()
    cloud = sky.cloud_fraction(w["time"], w["i_glob"], BLEISWIJK, 300.0)
    new = sky.sky_temperature(w["t_out"], w["rh_out"], cloud) - w["t_sky"]
    old = psy.sky_temperature(w["t_out"]) - w["t_sky"]
    rmse = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    assert abs(new.mean()) < 2.0 and abs(old.mean()) > 10.0
    assert rmse(new) < 0.5 * rmse(old)
    # by day the cloudiness read from the radiation follows the measured sky
    up = sky.clear_sky(w["time"], *BLEISWIJK) >= sky.STRONG_CLEAR
    assert np.corrcoef(cloud[up], (w["t_sky"] - w["t_out"])[up])[0, 1] > 0.4


def test_streaming_tracker_equals_the_series_version():
    w = load_bleiswijk()
    n = 12 * 24 * 5  # five days of 5-minute rows
    cloud = sky.cloud_fraction(w["time"][:n], w["i_glob"][:n], BLEISWIJK, 300.0)
    tracker = sky.CloudTracker(BLEISWIJK, 300.0)
    live = [tracker.update(t, i) for t, i in zip(w["time"][:n], w["i_glob"][:n], strict=True)]
    np.testing.assert_allclose(live, cloud, atol=1e-9)


def _day(kt: float, days: int = 2):
    time = np.datetime64("2009-06-21T00:00", "s") + np.arange(0, days * 86400, 300).astype(
        "timedelta64[s]")
    return time, kt * sky.clear_sky(time, *BLEISWIJK)


def test_clear_and_overcast_days_and_the_night():
    time, i = _day(1.0)
    c = sky.cloud_fraction(time, i, BLEISWIJK, 300.0)
    up = sky.clear_sky(time, *BLEISWIJK) >= sky.STRONG_CLEAR
    assert c[:12].tolist() == [sky.DEFAULT_CLOUD] * 12  # before the first daylight: the prior
    assert np.all(c[np.flatnonzero(up)[10]:][up[np.flatnonzero(up)[10]:]] < 1e-6)  # clear
    time, i = _day(0.2)
    c = sky.cloud_fraction(time, i, BLEISWIJK, 300.0)
    assert np.all(c[up & (np.arange(len(c)) > 200)] == pytest.approx(1.0))
    # the night after a mixed day relaxes from the evening's value towards the days' mean
    i = i * 0 + np.where(time < np.datetime64("2009-06-21T15:00"), 1.0, 0.4) * sky.clear_sky(
        time, *BLEISWIJK)
    c = sky.cloud_fraction(time, i, BLEISWIJK, 300.0)
    night = (time > np.datetime64("2009-06-21T21:00")) & (time < np.datetime64("2009-06-22T02:00"))
    evening = c[np.flatnonzero(up & (time < np.datetime64("2009-06-22")))[-1]]
    assert evening > 0.8 and np.all(np.diff(c[night]) < 0) and c[night][-1] > 0.2


def test_drivers_use_the_site_and_fall_back_without_one():
    gh = load_greenhouse("biskra-prototype")
    time, i = _day(1.0, days=1)
    n = len(time)
    cols = {"t_in": np.full(n, 15.0), "t_out": np.full(n, 10.0), "rh_out": np.full(n, 70.0),
            "i_glob": i, "wind": np.ones(n), "rh_in": np.full(n, 60.0)}
    series = Series(time, 300.0, cols)
    here = prepare_drivers(series, replace(gh, site=Site(*BLEISWIJK)))
    nowhere = prepare_drivers(series, replace(gh, site=None))
    assert here["cloud"][-1] < 0.05  # clear day measured where the sun was computed
    np.testing.assert_allclose(nowhere["cloud"], sky.DEFAULT_CLOUD)
    assert np.all(here["t_sky"][-1] < nowhere["t_sky"][-1] - 3.0)


def test_cli_site_option(tmp_path, capsys):
    import argparse

    from gateway.cli import main
    from gateway.cli.common import load_inputs
    from gateway.kitcsv import write_kit_csv

    with pytest.raises(SystemExit):
        main(["calibrate", "--data", "x.csv", "--greenhouse", "biskra-prototype", "--model",
              "prototype", "--site", "52.0"])
    assert "LAT,LON" in capsys.readouterr().err
    time, i = _day(1.0, days=1)
    n = len(time)
    write_kit_csv(tmp_path / "d.csv", time, {"t_in": np.full(n, 15.0), "t_out": np.full(n, 10.0),
                                             "i_glob": i, "wind": np.ones(n)})
    args = argparse.Namespace(data=str(tmp_path / "d.csv"), greenhouse="biskra-prototype",
                              model="prototype", step=300.0, site=BLEISWIJK)
    _, gh, _ = load_inputs(args)
    assert (gh.site.latitude, gh.site.longitude) == BLEISWIJK
    toml = tmp_path / "g.toml"
    toml.write_text('[geometry]\nfloor_area = 1.0\nvolume = 1.0\n', encoding="utf-8")
    args.greenhouse, args.site = str(toml), None
    _, gh, _ = load_inputs(args)
    assert gh.site is None
    assert "no [site]" in capsys.readouterr().err


def test_a_negative_offset_is_read_the_same_by_the_series_and_the_tracker():
    """A pyranometer reading below 0 (an offset, a dewy dome at low sun) counts as 0 wherever
    the radiation is read (gateway/model/solar.py ``measured_global``): the cloudiness of a whole
    series equals the one carried sample by sample, also where the offset falls in strong
    clear sky, and the model's drivers see 0."""
    time, i = _day(0.6)
    clear = sky.clear_sky(time, *BLEISWIJK)
    low = (clear >= sky.STRONG_CLEAR) & (clear < 250.0)  # the low morning and evening sun
    i = np.where(low, -8.0, i)
    tracker = sky.CloudTracker(BLEISWIJK, 300.0)
    one_at_a_time = [tracker.update(t, v) for t, v in zip(time, i, strict=True)]
    np.testing.assert_allclose(sky.cloud_fraction(time, i, BLEISWIJK, 300.0), one_at_a_time,
                               rtol=0, atol=1e-12)
    n = len(time)
    series = Series(time, 300.0, {"t_in": np.full(n, 15.0), "t_out": np.full(n, 10.0),
                                  "i_glob": i, "wind": np.ones(n)})
    x = prepare_drivers(series, load_greenhouse("biskra-prototype"))
    np.testing.assert_array_equal(x["i_glob"], np.where(low, 0.0, i))
    assert np.isnan(solar.measured_global([-8.0, np.nan])).tolist() == [False, True]

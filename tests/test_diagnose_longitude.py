"""The clock of the time-of-day features (docs/effects.md, "The clock of the time-of-day
features"): the diagnosis reads days and hours on the site's local mean solar time, so its
verdict does not depend on where the same house stands in longitude. The rule: the same data
with every timestamp shifted by Δ = −lon_shift/15 h and the site's longitude shifted by
lon_shift gives the same findings (starts shifted by Δ), the same free-run MAE up to the sun's
own motion over Δ, the same unexplained flag and the same signature bins in local solar time;
given the same residuals, the residual analysis is exactly the same."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from gateway.diagnose import day_test as dtm
from gateway.diagnose import diagnose
from gateway.diagnose import residuals as res
from gateway.model import solar
from gateway.model.drivers import clock_of
from tests import diagnose_cases as cases
from tests.diagnose_cases import piece_judge, shared_calibration_in_module  # noqa: F401 (fixtures)
from tests.test_diagnose import _misting
from tests.test_diagnose_unexplained_test import _synth

SHARP = re.compile(r"sharp time-of-day feature ([+-]\d+\.\d+) K at (\d\d:\d\d) local solar time")


def _shift(time: np.ndarray, lon_shift: float) -> np.ndarray:
    """``time`` moved by Δ = −lon_shift/15 h: the same local solar time at lon + lon_shift."""
    return time + np.timedelta64(int(round(-lon_shift * 240.0)), "s")


def test_solar_clock_is_utc_plus_longitude_over_15_to_the_half_hour():
    noon = np.array(["2026-06-01T12:00:00"], dtype="datetime64[s]")
    for lon, utc in ((-90.0, "18:00"), (120.0, "04:00"), (0.0, "12:00"), (4.4, "11:30"),
                     (-2.72, "12:00"), (-97.5, "18:30"), (-97.4, "18:30"), (-97.6, "18:30"),
                     (-101.0, "18:30"), (-104.0, "19:00")):
        t = np.array([f"2026-06-01T{utc}"], dtype="datetime64[s]")
        assert solar.solar_clock(lon).seconds(t)[0] % solar.DAY_S == 12 * 3600, lon
        assert solar.solar_clock(lon).name == "local solar time"
    no_site = solar.solar_clock(None)
    assert no_site.name == "UTC (no site)"
    assert no_site.seconds(noon)[0] == noon.astype(np.int64)[0]


def test_solar_clock_is_within_a_quarter_hour_of_the_suns_mean_time():
    """True solar time (the sun's hour angle, solar_position) is local mean solar time plus the
    equation of time, at any longitude; the clock keeps whole half-hours from UTC within
    15 min of the mean solar time."""
    t = np.datetime64("2026-03-01T00:00") + np.arange(0, 86400, 3700).astype("timedelta64[s]")
    unix = t.astype("datetime64[s]").astype(np.int64)
    for lon in (-90.0, -2.72, 4.4, 120.0, -101.0, 178.0):
        sun = solar.solar_position(t, 40.0, lon)
        mean_min = np.mod(unix / 60.0 + solar.mean_solar_offset_min(lon), 1440.0)
        true_min = np.mod(mean_min + sun.equation_of_time, 1440.0)
        np.testing.assert_allclose(true_min / 4.0 - 180.0, sun.hour_angle, atol=0.01)
        offset = solar.solar_clock(lon).offset_s
        assert offset % solar.CLOCK_STEP_S == 0
        assert abs(offset - 240.0 * lon) <= solar.CLOCK_STEP_S / 2, lon


@pytest.mark.parametrize("lon_shift", [-90.0, 120.0])
def test_residual_analysis_is_the_same_at_another_longitude(monkeypatch, lon_shift):
    """A scheduled dip 12:00–13:30 local solar time at lon 0, and the same residual at
    lon ``lon_shift``: the day test, the sharp feature, the hour profile and both flags'
    signatures are exactly the same. On the UTC clock (main before this change) the day test
    names other half-hours."""
    t, r, a = _synth(3, dip=0.6, shift=0.0, sd=0.15)
    here, there = solar.solar_clock(0.0), solar.solar_clock(lon_shift)
    t2 = _shift(t, lon_shift)
    d1 = dtm.day_test(t[a:], r[a:], t[:a], r[:a], clock=here)
    d2 = dtm.day_test(t2[a:], r[a:], t2[:a], r[:a], clock=there)
    assert d1 == d2 and d1.p < dtm.UNEXPLAINED_ALPHA and {24, 25} <= set(d1.bins)
    assert res.sharp_hours(t[a:], r[a:], t[:a], r[:a], here) == \
        res.sharp_hours(t2[a:], r[a:], t2[:a], r[:a], there)
    np.testing.assert_array_equal(res.hour_profile(t, r, here), res.hour_profile(t2, r, there))
    an = {"mean": 0.0, "mae": 0.3, "correlations": {}, "hour_profile": res.hour_profile(t, r, here),
          "clock": here.name, "acf_1h": np.nan, "acf_1d": np.nan, "change_points": {}}
    for test in (False, True):
        monkeypatch.setattr(res, "UNEXPLAINED_TEST", test)
        one = res.unexplained(an, r[:a], t, a, r[a:], clock=here)
        assert one == res.unexplained(an, r[:a], t2, a, r[a:], clock=there)
        assert "local solar time" in one[1] and "UTC" not in one[1]
    utc = dtm.day_test(t2[a:], r[a:], t2[:a], r[:a])  # main's clock
    assert utc.bins != d1.bins


def _case(tmp_path, lon_shift: float, post=None, effect=None, at: float = 3.6):
    """``diagnose`` of a diagnose_cases record at Almería moved by ``lon_shift`` (Δ a multiple
    of the 5-min grid, so the resampled rows are the same)."""
    series, gh, model, _ = cases.data(tmp_path, "almeria", effect, post=post, at=at)
    assert int(round(-lon_shift * 240.0)) % int(cases.STEP) == 0
    series = replace(series, time=_shift(series.time, lon_shift))
    gh = replace(gh, site=replace(gh.site, longitude=gh.site.longitude + lon_shift))
    return diagnose(series, gh, model), gh


def _same_verdict(d1, d2, lon_shift: float) -> None:
    """The rule's comparison; the MAE tolerance is the sun's own motion over Δ (its declination
    at the shifted instants moves the cloud fraction read from the radiation: 0.3 % here)."""
    assert [f.effect.name for f in d1.findings] == [f.effect.name for f in d2.findings]
    for f1, f2 in zip(d1.findings, d2.findings, strict=True):
        if f1.start is not None:
            lag = np.datetime64(f2.start.rstrip("Z")) - _shift(np.datetime64(f1.start.rstrip("Z")),
                                                               lon_shift)
            assert abs(lag / np.timedelta64(1, "s")) <= cases.STEP, (f1.start, f2.start)
    for part in ("before", "after"):
        assert getattr(d2, part)["free_run"]["mae"] == pytest.approx(
            getattr(d1, part)["free_run"]["mae"], rel=0.01)
    assert d1.unexplained == d2.unexplained
    p1, p2 = d1.analysis_after["hour_profile"], d2.analysis_after["hour_profile"]
    assert np.nanargmax(np.abs(p1)) == np.nanargmax(np.abs(p2))
    s1, s2 = SHARP.search(d1.signature), SHARP.search(d2.signature)
    assert (s1 is None) == (s2 is None), (d1.signature, d2.signature)
    if s1 and s2:
        assert s1[2] == s2[2] and abs(float(s1[1]) - float(s2[1])) <= 0.05, (s1[0], s2[0])


@pytest.mark.slow
@pytest.mark.parametrize("lon_shift", [-90.0, 120.0])
def test_misting_verdict_is_the_same_at_another_longitude(tmp_path, lon_shift):
    """tests/test_diagnose.py's misting (outside the library, at 11:00 and 15:00 UTC at
    Almería) with the house moved by −90° or +120° (Δ = +6 h, −8 h): unexplained, its sharp
    feature at the same local solar half-hour (−1.08 K at 15:00 at Almería, whose clock is UTC;
    on the UTC clock the moved copies read 21:00 and 07:00)."""
    d1, gh = _case(tmp_path, 0.0, post=_misting)
    d2, gh2 = _case(tmp_path, lon_shift, post=_misting)
    assert clock_of(gh2).name == "local solar time"
    assert d1.unexplained and SHARP.search(d1.signature), d1.signature
    _same_verdict(d1, d2, lon_shift)


@pytest.mark.slow
@pytest.mark.usefixtures("piece_judge")
def test_heater_finding_is_the_same_at_another_longitude(tmp_path):
    """A 25 W m-2 heater from day 3.6 (tests/test_diagnose.py) with the house moved by −90°:
    the same finding, its start shifted by Δ."""
    d1, _ = _case(tmp_path, 0.0, effect="heater")
    d2, _ = _case(tmp_path, -90.0, effect="heater")
    assert d1.findings and d1.findings[0].effect.name in cases.EQUIVALENT["heater"]
    _same_verdict(d1, d2, -90.0)

"""Every injected effect changes what it should, and only from its start time."""

from __future__ import annotations

import numpy as np
import pytest

from training.simulate import simulate
from training.simulate.effects import (
    EFFECTS,
    CoverTransmission,
    EffectSpecError,
    ExtraLeakage,
    Heater,
    SensorDrift,
    parse_effect,
)

START = "2020-04-01"
EFFECT_AT = np.datetime64("2020-04-02T06:00", "s")
DAYS = 2.0
PHYSICAL_STATES = ("t_air", "t_cover", "t_floor", "c_air")


@pytest.fixture(scope="module")
def base():
    return simulate("almeria", "almeria", START, days=DAYS, seed=5)


def run_with(spec: str):
    return simulate("almeria", "almeria", START, days=DAYS, seed=5, effects=[spec])


def split(result) -> tuple[np.ndarray, np.ndarray]:
    """Masks of samples before and after the effect's start (states change after it)."""
    return result.time <= EFFECT_AT, result.time > EFFECT_AT


def assert_same_before(base, other, before):
    for name in PHYSICAL_STATES:
        np.testing.assert_array_equal(base.series[name][before], other.series[name][before])
    for name, values in base.columns.items():
        np.testing.assert_array_equal(values[before], other.columns[name][before])


def test_cover_transmission(base):
    r = run_with("cover_transmission@2020-04-02T06:00:factor=0.5")
    before, after = split(r)
    assert_same_before(base, r, before)
    sunny = after & (base.series["i_in"] > 50)
    np.testing.assert_allclose(r.series["i_in"][sunny], 0.5 * base.series["i_in"][sunny])
    assert np.mean(r.series["t_air"][sunny]) < np.mean(base.series["t_air"][sunny]) - 0.5
    assert np.nanmean(r.columns["i_in"][sunny]) < 0.6 * np.nanmean(base.columns["i_in"][sunny])
    assert r.truth["effects"] == [{"effect": "cover_transmission", "start": "2020-04-02T06:00:00Z",
                                   "kind": "physics", "params": {"factor": 0.5},
                                   "units": {"factor": "-"}}]


def test_extra_leakage(base):
    r = run_with("extra_leakage@2020-04-02T06:00:flow=3")
    before, after = split(r)
    assert_same_before(base, r, before)
    np.testing.assert_allclose(r.series["g_extra"][after], 3.0)
    assert np.all(r.series["g_extra"][1:][before[1:]] == 0.0)
    assert np.all(r.series["g_leak"][after] >= 3.0)


def test_heater_at_night_only(base):
    r = run_with("heater@2020-04-02T06:00:power=50,night_only=1")
    before, after = split(r)
    assert_same_before(base, r, before)
    night = after & (r.series["i_glob"] < 1.0)
    day = after & (r.series["i_glob"] > 50.0)
    np.testing.assert_allclose(r.series["q_heater"][night], 50.0)
    assert np.all(r.series["q_heater"][day] == 0.0)
    assert np.mean(r.series["t_air"][night] - base.series["t_air"][night]) > 1.0


def test_heater_with_setpoint_holds_the_air():
    r = simulate("almeria", "almeria", START, days=DAYS, seed=5,
                 effects=[Heater(start=np.datetime64(START), power=200.0, setpoint=17.0)])
    s = r.series
    assert s["t_air"][0] < 16.0  # the spin-up ran without the heater
    assert s["t_air"][30:].min() > 16.0
    assert np.nanmax(s["q_heater"]) <= 200.0 and np.nanmin(s["q_heater"]) >= 0.0


def test_thermal_mass(base):
    r = run_with("thermal_mass@2020-04-02T06:00:factor=3")
    before, after = split(r)
    assert_same_before(base, r, before)
    np.testing.assert_allclose(r.series["cap_air"][after], 3.0 * base.series["cap_air"][after])
    # More mass: slower air temperature changes.
    rate = np.abs(np.diff(r.series["t_air"]))[after[1:]]
    rate_base = np.abs(np.diff(base.series["t_air"]))[after[1:]]
    assert rate.mean() < rate_base.mean()


def test_sensor_radiation_bias(base):
    r = run_with("sensor_radiation_bias@2020-04-02T06:00:k=0.01")
    before, after = split(r)
    assert_same_before(base, r, before)
    for name in PHYSICAL_STATES:  # a sensor effect leaves the physics alone
        np.testing.assert_array_equal(base.series[name], r.series[name])
    diff = r.columns["t_in"] - base.columns["t_in"]
    sunny = after & (r.series["i_in"] > 100)
    dark = after & (r.series["i_in"] <= 0)
    expected = 0.01 * r.series["i_in"][sunny]
    np.testing.assert_allclose(diff[sunny], expected, atol=0.011)  # HC2S3 resolution 0.01
    assert np.nanmax(np.abs(diff[dark])) < 1e-9
    # A sun-heated sensor body also reads a lower relative humidity.
    assert np.nanmean(r.columns["rh_in"][sunny] - base.columns["rh_in"][sunny]) < -3.0


def test_sensor_drift(base):
    r = run_with("sensor_drift@2020-04-02T06:00:rate=0.5")
    before, after = split(r)
    assert_same_before(base, r, before)
    days = (r.time - EFFECT_AT).astype(np.int64) / 86400.0
    diff = r.columns["t_in"] - base.columns["t_in"]
    np.testing.assert_allclose(diff[after], 0.5 * days[after], atol=0.011)
    np.testing.assert_array_equal(r.columns["rh_in"], base.columns["rh_in"])


def test_spec_parsing_and_errors():
    t0 = np.datetime64("2009-11-01", "s")
    e = parse_effect("cover_transmission@2009-11-08T10:00:factor=0.7", t0)
    assert e == CoverTransmission(start=np.datetime64("2009-11-08T10:00", "s"), factor=0.7)
    assert parse_effect("extra_leakage:ach=4", t0) == ExtraLeakage(start=t0, ach=4.0)
    assert parse_effect("sensor_drift@2009-11-02:rate=-0.1", t0) == SensorDrift(
        start=np.datetime64("2009-11-02", "s"), rate=-0.1)
    assert parse_effect("none", t0) is None
    for bad in ("fog@2009-11-02", "heater:pwr=3", "heater:power=abc", "extra_leakage",
                "cover_transmission:factor=-1"):
        with pytest.raises(EffectSpecError) as info:
            parse_effect(bad, t0)
        for name in EFFECTS:  # every error lists the known effects
            assert name in str(info.value)

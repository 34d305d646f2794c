"""The generality suite's front-end: every generator gives kit columns at 5-minute rows with the
change where it says; the reference simulator's misting and vent cap (written for the suite) act."""

from __future__ import annotations

import numpy as np
import pytest

from tests.generality.cases import MIN_VISIBLE_K, verdict, visible_change
from tests.generality.generators import KIT, generate
from tests.generality.windows import bleiswijk_window

SETPOINT = 12.0


@pytest.fixture(scope="module")
def window():
    return bleiswijk_window("2009-10-20T00:00", 2.0, "two days")  # the change at day 1.4


@pytest.mark.parametrize("generator", ["refsim"])  # twonode: the same wrapper, 3x slower
def test_kit_columns_at_five_minutes(window, generator):
    d = generate(generator, window, "heater", change_day=1.4)
    assert set(d.columns) == set(KIT)
    assert np.all(np.diff(d.time).astype(int) == 300)
    assert d.start == window.at_day(1.4)
    after = d.time >= d.start
    base = generate(generator, window, "none", change_day=1.4)
    warmer = np.nanmean(d.columns["t_in"][after] - base.columns["t_in"][after])
    assert warmer > 1.0  # a 25 W m-2 heater in an 877 m2 house
    np.testing.assert_array_equal(d.columns["t_in"][~after], base.columns["t_in"][~after])
    gh = d.greenhouse()
    assert (gh.site.latitude, gh.site.longitude) == (window.latitude, window.longitude)


def test_row_interval_keeps_every_kth_reading(window):
    """A logger's row interval (tests/generality/row_interval.py): point samples of the same
    1-minute readings, so 900-s rows are every third 300-s row and 60-s rows hold the 300-s
    ones; intervals that are not whole minutes are refused."""
    five = generate("refsim", window, "none")
    fifteen = generate("refsim", window, "none", row_s=900.0)
    np.testing.assert_array_equal(fifteen.time, five.time[::3])
    for c in KIT:
        np.testing.assert_array_equal(fifteen.columns[c], five.columns[c][::3])
    one = generate("refsim", window, "none", row_s=60.0)
    assert np.all(np.diff(one.time).astype(int) == 60)
    np.testing.assert_array_equal(one.columns["t_in"][::5], five.columns["t_in"])
    for bad in (450.0, 90.0):
        with pytest.raises(ValueError, match="row interval"):
            generate("refsim", window, "none", row_s=bad)


def test_reference_simulator_misting_cools_at_midday(window):
    mist = generate("refsim", window, "misting", change_day=1.0)
    base = generate("refsim", window, "none", change_day=1.0)
    hours = (mist.time - mist.time.astype("datetime64[D]")).astype("timedelta64[m]").astype(float) / 60
    noon = (mist.time >= mist.start) & (hours >= 11.5) & (hours < 14.5)
    night = (mist.time >= mist.start) & (hours < 6)
    assert np.nanmean(mist.columns["t_in"][noon] - base.columns["t_in"][noon]) < -0.5
    assert abs(np.nanmean(mist.columns["t_in"][night] - base.columns["t_in"][night])) < 0.2


def test_verdicts():
    found = {"findings": [{"effect": "heat_source"}], "start_error_h": 3.0, "cut": 0.4,
             "p_value": 0.01, "unexplained": False}
    assert verdict("night_heater", found)["ok"]
    assert not verdict("night_heater", {**found, "start_error_h": -13.0})["ok"]
    assert not verdict("night_heater", {**found, "p_value": 0.2})["ok"]
    assert not verdict("drift", found)["ok"]
    assert verdict("none", found)["false_alarm"]
    assert verdict("none", {**found, "findings": []})["ok"]
    assert verdict("misting", {**found, "unexplained": True})["ok"]
    assert verdict("drift", {**found, "findings": [{"effect": "sensor_drift"}], "p_value": None})["ok"]
    quiet = {**found, "findings": [], "visible_k": 0.0}  # a change the reading does not show
    assert verdict("controller", quiet) == {"invisible": True, "false_alarm": False, "ok": True}
    assert verdict("controller", {**found, "visible_k": 0.01})["false_alarm"]
    assert not verdict("controller", {**quiet, "visible_k": 0.3})["ok"]  # shown, not flagged


def test_a_change_the_reading_does_not_show_is_measured_as_such(window):
    """The reference simulator's vent cap binds only when the vents open wide: on two autumn
    days it moves the reading by less than MIN_VISIBLE_K; the heater by more than 1 K."""
    without = generate("refsim", window, "none").columns["t_in"]
    capped = visible_change(generate("refsim", window, "controller", change_day=1.4), without)
    heater = visible_change(generate("refsim", window, "heater", change_day=1.4), without)
    assert heater > 1.0
    assert capped < MIN_VISIBLE_K


def test_the_heated_study_case_is_a_public_call_that_heats_from_the_first_sample():
    """tests/generality/heated_study.py's heated house: ``generate`` with the two-node house's
    ``thermostat`` from day 0 at a setpoint of its own, changing no module state. One winter day:
    the heating holds the air near the setpoint (a proportional 60 W m-2 K-1 pipe: it sits a
    little below), and where the unheated house is warmer than the setpoint nothing changes."""
    from tests.generality import generators

    w = bleiswijk_window("2009-11-26T00:00", 1.0, "one winter day")  # 7-9 °C outside
    specs = dict(generators.TWONODE_SPECS)
    heated = generate("twonode", w, "thermostat", change_day=0.0, amount=SETPOINT)
    base = generate("twonode", w, "none")
    assert generators.TWONODE_SPECS == specs
    assert heated.start == w.start and heated.size == f"thermostat amp={SETPOINT:g}"
    t, t0 = heated.columns["t_in"], base.columns["t_in"]
    assert np.all(t >= t0 - 0.05)  # the same sensor noise on both
    cold = t0 < SETPOINT - 3.0  # unheated, the air more than 3 K below the setpoint
    assert cold.sum() > 100  # most of the day
    assert np.all(np.abs(t[cold] - SETPOINT) < 1.0)
    with pytest.raises(ValueError, match="two-node"):
        generate("refsim", w, "heater", amount=10.0)
    with pytest.raises(ValueError, match="thermostat"):
        generate("refsim", w, "thermostat")

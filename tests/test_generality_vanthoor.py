"""Physics sanity of the held-out generator (tests/generality/vanthoor.py): the heat balance
closes, every change acts in the direction its physics says, the kit readings look like a kit's.

Only sanity: nothing here compares it with our model (it is held out from all tuning).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.generality import kit_sensors, vanthoor
from tests.generality.windows import bleiswijk_window

START = "2009-10-20T00:00"  # sunny autumn days, the change from the second (00:00 UTC)


@pytest.fixture(scope="module")
def window():
    return bleiswijk_window(START, 1.6, "sanity")  # up to 14:24 UTC of the second day


@pytest.fixture(scope="module")
def runs(window):
    mp = pytest.MonkeyPatch()
    mp.setattr(vanthoor, "SUBSTEP", 60.0)  # half the cost; the tests compare runs alike
    at = window.at_day(1.0)
    sizes = {"whitening": 0.5, "leakage": 5.0, "heater": 30.0, "night_heater": 30.0,
             "thermal_mass": 60.0, "sun_sensor": 0.006, "misting": 3e-5, "controller": 0.0}
    try:
        out = {"none": vanthoor.Glasshouse(vanthoor.Venlo(), window).run(spinup_days=0)}
        for kind, amount in sizes.items():
            change = vanthoor.Change(kind, at, amount)
            out[kind] = vanthoor.Glasshouse(vanthoor.Venlo(), window, change).run(spinup_days=0)
    finally:
        mp.undo()
    return out


def _masks(window):
    second = np.arange(len(window.time)) >= 1440
    day = second & (window.i_glob > 50)
    night = second & (window.i_glob < 1)
    return second, day, night


def test_heat_balance_closes_and_states_are_plausible(runs, window):
    for kind, r in runs.items():
        assert r.energy_residual < 1e-6, kind  # stored heat = fluxes applied, every sub-step
    base = runs["none"]
    assert np.all(np.isfinite(base.t_air)) and np.all(base.vp_air > 0)
    rh = 100 * base.vp_air / vanthoor.saturation_vp(base.t_air)
    assert rh.max() < 101 and rh.min() > 30
    excess = base.t_air - window.t_out
    _, day, night = _masks(window)
    assert excess[day].mean() > 2.0  # a glasshouse warms in the sun
    assert -2.0 < excess[night].mean() < 3.0  # and sits near the outside air at night, unheated


def test_each_change_acts_in_its_direction(runs, window):
    second, day, night = _masks(window)
    base = runs["none"]
    d = {k: r.t_air - base.t_air for k, r in runs.items()}
    np.testing.assert_allclose(d["whitening"][~second], 0.0, atol=1e-9)  # nothing before it
    assert d["whitening"][day].mean() < -0.5
    assert d["heater"][second].mean() > 1.0
    assert d["night_heater"][night].mean() > 1.0
    assert abs(d["night_heater"][day].mean()) < d["night_heater"][night].mean() / 2
    gap = np.abs(base.t_air - window.t_out)[second].mean()
    assert np.abs(runs["leakage"].t_air - window.t_out)[second].mean() < gap  # closer to outside
    swing = np.ptp(base.t_air[second])
    assert np.ptp(runs["thermal_mass"].t_air[second]) < 0.9 * swing  # water damps the day
    body = runs["sun_sensor"].t_body - base.t_body  # same air: only the sun on the body differs
    assert body[day].mean() > 0.5 and np.abs(body[night]).mean() < 0.01
    np.testing.assert_allclose(runs["sun_sensor"].t_air, base.t_air)  # the air is untouched
    mist = runs["misting"]
    rh = {k: r.vp_air / vanthoor.saturation_vp(r.t_air) for k, r in (("mist", mist), ("base", base))}
    assert d["misting"][day].mean() < -0.3 and (rh["mist"] - rh["base"])[day].mean() > 0.01
    assert not np.allclose(runs["controller"].vent[second], base.vent[second])


def test_kit_readings_are_those_of_a_kit(window, runs):
    r = runs["none"]
    drift = np.where(np.arange(len(window.time)) >= 1440, 0.5, 0.0)
    cols = kit_sensors.kit_columns(r.t_body, r.vp_air, window, seed=3, drift=drift)
    assert set(cols) == {"t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind"}
    assert all(len(v) == len(range(0, len(window.time), 5)) for v in cols.values())  # 5-min rows
    t = cols["t_in"][np.isfinite(cols["t_in"])]
    np.testing.assert_allclose(t, np.round(t, 1))  # DHT22: 0.1 K steps
    err = cols["t_in"] - r.t_body[::5]
    first, second = err[:288], err[288:]
    assert abs(np.nanmean(second) - np.nanmean(first) - 0.5) < 0.1  # the drift, nothing else
    assert np.nanstd(first) < 0.15 and abs(np.nanmean(first)) <= 0.55  # noise and bias of a DHT22
    assert np.all(cols["i_glob"] >= 0)

"""Simulator physics: energy and water balances, steady states by hand, Kittas flow, sanity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from training.simulate import simulate
from training.simulate.effects import Heater, PhysicsDrivers
from training.simulate.integrate import State, SubstepInputs, run, vapour_concentration
from training.simulate.plant import ALMERIA, PROTOTYPE
from training.simulate.ventilation import kittas_flow, leakage_flow, roof_area, side_area
from training.simulate.weather import Weather

RHO_CP = 1.2 * 1005.0


def constant_weather(days: float, t_out: float = 10.0, rh: float = 60.0, i_glob: float = 0.0,
                     wind: float = 0.0, t_sky: float | None = None) -> Weather:
    n = int(days * 1440)
    time = np.datetime64("2020-01-01T00:00", "s") + np.arange(n) * np.timedelta64(60, "s")

    def full(v: float) -> np.ndarray:
        return np.full(n, float(v))

    return Weather(time, full(t_out), full(rh), full(i_glob), full(wind),
                   full(t_out if t_sky is None else t_sky), full(0.0), "constant", 35.0)


@pytest.fixture(scope="module")
def busy_run():
    """Two sunny Almería days with vents, condensation, a heater and a thermal-mass change."""
    return simulate("almeria", "almeria", "2020-04-01", days=2.0, seed=3, effects=[
        "heater@2020-04-01T20:00:power=40,setpoint=18",
        "thermal_mass@2020-04-02T06:00:factor=2",
        "extra_leakage@2020-04-02T12:00:ach=3",
    ])


def test_node_energy_balances_close(busy_run):
    s = busy_run.series
    air = (s["q_solar_air"] + s["q_crop_air"] + s["q_heater"] + s["q_fog"]
           + s["q_conv_floor_air"] - s["q_conv_air_cover"] - s["q_vent"] - s["q_leak"])
    cover = (s["q_solar_cover"] + s["q_condensation"] + s["q_conv_air_cover"]
             + s["q_lw_floor_cover"] - s["q_conv_cover_out"] - s["q_lw_cover_sky"]
             - s["q_lw_cover_surr"])
    floor = (s["q_solar_floor"] - s["q_conv_floor_air"] - s["q_lw_floor_cover"]
             - s["q_lw_floor_sky"] - s["q_cond_floor_deep"])
    deep = s["q_cond_floor_deep"] - s["q_cond_deep_ground"]
    for storage, fluxes in ((s["s_air"], air), (s["s_cover"], cover), (s["s_floor"], floor),
                            (s["s_deep"], deep)):
        np.testing.assert_allclose(storage[1:], fluxes[1:], atol=1e-6)
    # Storage rates agree with the stored temperatures (capacity constant within an interval).
    np.testing.assert_allclose(s["s_air"][1:], s["cap_air"][1:] * np.diff(s["t_air"]) / 60.0,
                               atol=1e-6)
    assert np.ptp(s["q_heater"][1:]) > 10.0 and np.ptp(s["cap_air"][1:]) > 1000.0


def test_whole_house_energy_balance(busy_run):
    s = busy_run.series
    storage = s["s_air"] + s["s_cover"] + s["s_floor"] + s["s_deep"]
    sources = (s["q_solar_cover"] + s["q_solar_air"] + s["q_solar_crop"] + s["q_solar_floor"]
               + s["q_heater"] + s["q_condensation"] + s["q_fog"] - s["q_transpiration"])
    losses = (s["q_vent"] + s["q_leak"] + s["q_conv_cover_out"] + s["q_lw_cover_sky"]
              + s["q_lw_cover_surr"] + s["q_lw_floor_sky"] + s["q_cond_deep_ground"])
    np.testing.assert_allclose(storage[1:], (sources - losses)[1:], atol=1e-6)
    # Over two days the storage terms are small against the solar input.
    assert abs(np.mean(storage[1:])) < 0.1 * np.mean(s["q_solar_floor"][1:] + s["q_solar_crop"][1:])


def test_water_balance_closes(busy_run):
    s = busy_run.series
    np.testing.assert_allclose(
        s["w_storage"][1:],
        (s["w_transpiration"] - s["w_vent"] - s["w_condensation"] - s["w_fog"])[1:], atol=1e-12)
    height = ALMERIA.volume / ALMERIA.floor_area
    np.testing.assert_allclose(s["w_storage"][1:], height * np.diff(s["c_air"]) / 60.0, atol=1e-12)
    assert np.nanmax(s["w_transpiration"]) > 5e-5  # the crop transpires in the sun
    assert np.nanmax(s["rh_air"]) <= 100.0 + 1e-9


def _linear_plant():
    """A prototype with every nonlinear path made linear, so the steady state is a hand sum."""
    return PROTOTYPE.with_(
        h_in_a=0.0, h_in_b=5.0, h_out_a=2.8, h_out_b=3.0, eps_cover=0.0, eps_floor=0.0,
        h_floor_up=0.0, h_floor_down=0.0, fixed_roof_area=0.0, fixed_side_area=0.0,
        lai_start=0.0, floor_capacity=1e4, deep_capacity=2e4, ground_offset=0.0)


def _state(t: float, rh: float = 60.0) -> State:
    c = float(vapour_concentration(t, rh))
    return State(t, t, t, t, c)


def _inputs(plant, wx: Weather, substeps: int = 2) -> SubstepInputs:
    n_sub = (len(wx) - 1) * substeps

    def full(v):
        return np.full(n_sub, float(v[0]))

    return SubstepInputs(full(wx.t_out), full(vapour_concentration(wx.t_out, wx.rh_out)),
                         full(wx.i_glob), full(wx.wind), full(wx.t_sky), np.zeros(n_sub),
                         float(wx.t_out[0]) + plant.ground_offset, np.zeros(len(wx), bool),
                         wx.rain)


def test_unheated_house_relaxes_to_outside():
    plant = PROTOTYPE.with_(lai_start=0.0, ground_offset=0.0)
    wx = constant_weather(3.0, t_out=8.0, t_sky=8.0)
    traj = run(plant, _inputs(plant, wx), PhysicsDrivers.neutral((len(wx) - 1) * 2),
               _state(25.0), 60.0, 2)
    assert traj.t_a[0] == 25.0
    assert abs(traj.t_a[-1] - 8.0) < 0.01
    assert abs(traj.t_d[-1] - 8.0) < 0.1  # the slow soil mode is still settling


@pytest.mark.parametrize("power", [20.0, 60.0])
def test_heated_steady_state_matches_hand_conductance(power):
    plant = _linear_plant()
    t_out = 5.0
    wx = constant_weather(2.0, t_out=t_out)
    result = simulate(plant, wx, effects=[Heater(start=wx.time[0], power=power)])
    # Hand calculation, per m2 of floor [W m-2 K-1]:
    ratio = plant.cover_area / plant.floor_area
    k_cover = ratio / (1.0 / 5.0 + 1.0 / 2.8)  # inner 5, outer 2.8 + 3.0 * 0 wind
    k_floor = 1.0 / (1.0 / 0.3 + 1.0 / plant.k_floor_deep + 1.0 / plant.k_deep_ground)
    k_leak = RHO_CP * plant.leak_ach * plant.volume / 3600.0 / plant.floor_area
    expected = power / (k_cover + k_floor + k_leak)
    assert result.series["t_air"][-1] - t_out == pytest.approx(expected, rel=2e-3)


def test_kittas_flow_by_hand():
    a_r, a_s, dt, t_out, u, h, cd, cw = 10.0, 30.0, 6.0, 15.0, 3.0, 2.8, 0.65, 0.1
    # (A_r A_s)^2 / (A_r^2 + A_s^2) = 90000 / 1000 = 90 m4; 2 g h dT / T = 2 * 9.81 * 2.8 * 6 / 288.15
    stack = 90.0 * 2.0 * 9.81 * 2.8 * 6.0 / 288.15
    wind = 20.0**2 * 0.1 * 9.0  # ((A_r + A_s)/2)^2 Cw u^2
    expected = 0.65 * math.sqrt(stack + wind)
    assert kittas_flow(a_r, a_s, dt, t_out, u, h, cd, cw, 0.0) == pytest.approx(expected)
    # Buoyancy alone is symmetric in dT; the single-roof-opening term adds to it.
    assert kittas_flow(a_r, a_s, -dt, t_out, 0.0, h, cd, cw, 0.0) == pytest.approx(
        kittas_flow(a_r, a_s, dt, t_out, 0.0, h, cd, cw, 0.0))
    assert kittas_flow(a_r, 0.0, dt, t_out, 0.0, h, cd, cw, 0.5) == pytest.approx(
        cd * (a_r / 3.0) * math.sqrt(0.5 * 9.81 * dt / 288.15))


def test_vent_areas_and_leakage():
    full_roof = roof_area(100.0, 5, 8.36, 0.73, 45.0)
    assert full_roof == pytest.approx(5 * 2 * 8.36 * 0.73 * math.sin(math.radians(22.5)))
    assert roof_area(0.0, 5, 8.36, 0.73, 45.0) == 0.0
    assert side_area(50.0, 2, 32.75, 1.90) == pytest.approx(32.75 * 1.90)
    assert leakage_flow(3600.0, 1.0, 0.5, 2.0) == pytest.approx(2.0)


def test_prototype_sunny_days_and_nights_are_sensible():
    r = simulate("prototype", "biskra", "2019-01-26", days=3.0, seed=2)
    s = r.series
    rise = s["t_air"] - s["t_out"]
    day = s["i_glob"] > 400.0
    night = s["i_glob"] <= 0.0
    assert 5.0 < rise[day].max() < 20.0
    assert np.abs(rise[night]).max() < 4.0
    assert np.all(s["vent_roof"] == 0.0)


def test_almeria_vents_hold_a_sunny_summer_day():
    r = simulate("almeria", "almeria", "2020-04-20", days=2.0, seed=4)
    s = r.series
    assert s["vent_roof"].max() > 30.0 and s["vent_side"].max() > 0.0
    assert 25.0 < s["t_air"].max() < 29.0
    assert np.nanmax(s["g_vent"]) > 5.0  # m3 s-1
    # The roof opens before the side vents.
    first_roof = np.argmax(s["vent_roof"] > 0)
    first_side = np.argmax(s["vent_side"] > 0)
    assert first_roof < first_side

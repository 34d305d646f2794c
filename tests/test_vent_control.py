"""Controller-moved vents (gateway/model/vent_control.py): units, bounds, a known value, the
exact slope, and the prototype with the term added."""

import math

import numpy as np
import pytest
from conftest import almeria_like_series

from gateway.model.drivers import prepare_drivers
from gateway.model.prototype import AirLeakage, build_prototype
from gateway.model.vent_control import SMOOTH_K, ControlledVentilation, soft_excess, soft_step


def test_parameters_units_bounds_and_the_sunlit_search():
    term = ControlledVentilation()
    c_vc, t_vc = term.parameters
    assert (c_vc.name, c_vc.unit.split()[0], c_vc.lower, c_vc.upper) == ("c_vc", "m", 0.0, 1e-3)
    assert (t_vc.name, t_vc.unit, t_vc.lower, t_vc.upper) == ("t_vc", "°C", 15.0, 35.0)
    assert c_vc.active.name == t_vc.active.name == "sunlit"
    assert term.requires == ("t_out", "i_glob")


def test_soft_excess_is_a_smooth_max_and_its_derivative_the_logistic():
    z = np.array([-10.0, 0.0, 10.0])
    np.testing.assert_allclose(soft_excess(z), [0.0, SMOOTH_K * math.log(2.0), 10.0], atol=1e-6)
    np.testing.assert_allclose(soft_step(z), [0.0, 0.5, 1.0], atol=1e-6)
    h = 1e-5
    zz = np.linspace(-3.0, 3.0, 13)
    np.testing.assert_allclose(soft_step(zz), (soft_excess(zz + h) - soft_excess(zz - h)) / (2 * h),
                               rtol=1e-6)


def test_known_value_well_above_the_setpoint_is_leakage_scaled_by_the_excess():
    """3 K above T_vc = 25 °C (σ ≈ 3 K), 5 K above T_out: Q = −C_vc ρ 3 K 5 K, the same as the
    leakage term (III.19) with C_loss = 3 K × C_vc."""
    rho, c_vc = 1.2, 2e-4
    x = {"t_out": np.array([23.0]), "i_glob": np.array([400.0])}
    p = {"c_vc": np.array([[c_vc]]), "t_vc": np.array([[25.0]])}
    q = ControlledVentilation(rho).flux(p, x, np.array([[28.0]]), 0)
    expected = -c_vc * rho * float(soft_excess(np.array(3.0))) * 5.0
    np.testing.assert_allclose(q, expected, rtol=1e-12)
    np.testing.assert_allclose(q, -c_vc * rho * 3.0 * 5.0, rtol=1e-3)
    leak = AirLeakage(rho).flux({"c_loss": np.array([[3.0 * c_vc]])}, x, np.array([[28.0]]), 0)
    np.testing.assert_allclose(q, leak, rtol=1e-3)
    below = ControlledVentilation(rho).flux(p, x, np.array([[20.0]]), 0)  # 5 K under: closed
    assert abs(float(below[0, 0])) < 1e-5 * abs(expected)
    night = {"t_out": x["t_out"], "i_glob": np.array([0.0])}  # no sun: the leakage's alone
    assert float(ControlledVentilation(rho).flux(p, night, np.array([[28.0]]), 0)[0, 0]) == 0.0


def test_slope_is_minus_the_derivative_of_the_flux():
    rng = np.random.default_rng(3)
    term = ControlledVentilation(1.2)
    x = {"t_out": rng.uniform(10.0, 30.0, 200), "i_glob": rng.choice([0.0, 300.0], 200)}
    p = {"c_vc": rng.uniform(0.0, 1e-3, (4, 1)), "t_vc": rng.uniform(15.0, 35.0, (4, 1))}
    state = rng.uniform(10.0, 40.0, (4, 200))
    t = slice(0, 200)
    g, s, k = term.linearised(p, x, state, t)
    h = 1e-5
    num = -(term.flux(p, x, state + h, t) - term.flux(p, x, state - h, t)) / (2 * h)
    np.testing.assert_allclose(k, num, rtol=1e-5, atol=1e-12)
    g0, s0 = term.coefficients(p, x, state, t)
    np.testing.assert_allclose(g, g0, rtol=1e-12)
    np.testing.assert_allclose(s, s0, rtol=1e-12)


@pytest.fixture(scope="module")
def with_term(weather_minutes, prototype_gh):
    series = almeria_like_series(weather_minutes, days=1)
    return build_prototype(prototype_gh, vent_control=True), prepare_drivers(series, prototype_gh)


def test_prototype_with_the_term_has_six_parameters_and_zero_gain_changes_nothing(with_term,
                                                                                  prototype_gh):
    model, x = with_term
    plain = build_prototype(prototype_gh)
    assert model.names == [*plain.names, "c_vc", "t_vc"]
    theta = model.defaults(prototype_gh)
    theta[model.index("c_vc")] = 0.0
    starts = np.arange(0, 1200, 7)
    got = model.forecast(np.repeat(theta[None, :], len(starts), 0), x, prototype_gh, 60.0, starts, 30)
    ref = plain.forecast(np.repeat(theta[None, :4], len(starts), 0), x, prototype_gh, 60.0, starts, 30)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)


def test_a_low_setpoint_cools_a_warm_sunlit_forecast_toward_the_outside(with_term, prototype_gh):
    model, x = with_term
    theta = model.defaults(prototype_gh)
    starts = np.arange(0, 1200, 7)
    sunlit = np.array([np.all(x["i_glob"][s:s + 31] > 5.0) for s in starts])
    night = np.array([np.all(x["i_glob"][s:s + 31] <= 5.0) for s in starts])
    warm = (x["t_in"][starts] > x["t_out"][starts] + 1.0) & sunlit
    assert warm.sum() > 10 and night.sum() > 10
    runs = []
    for c_vc in (0.0, 5e-4):
        theta[model.index("c_vc")], theta[model.index("t_vc")] = c_vc, 15.0
        runs.append(model.forecast(np.repeat(theta[None, :], len(starts), 0), x, prototype_gh, 60.0,
                                   starts, 30))
    assert np.all(runs[1][warm] < runs[0][warm])
    np.testing.assert_array_equal(runs[1][night], runs[0][night])  # the vents act by day only

"""Leakage growing with the wind (gateway/model/wind_leakage.py): units, bounds, a known value,
the slope, and the structured prototype with the term added."""

import numpy as np
from conftest import almeria_like_series

from gateway.diagnose.structure import structure
from gateway.model.drivers import prepare_drivers
from gateway.model.prototype import AirLeakage, build_prototype
from gateway.model.wind_leakage import C_WL_MAX, WindLeakage


def test_parameter_unit_bounds_and_the_always_active_search():
    term = WindLeakage()
    (c_wl,) = term.parameters
    assert (c_wl.name, c_wl.unit.split()[0], c_wl.lower, c_wl.upper) == ("c_wl", "-", 0.0, C_WL_MAX)
    assert c_wl.active.name == "always"
    assert term.requires == ("t_out", "wind")
    assert term.linear_in_parameters and not term.state_dependent
    # at 4 m s-1 the bound reaches the prototype's constant leakage bound (III.19)
    (c_loss,) = AirLeakage().parameters
    assert np.isclose(4.0 * C_WL_MAX, c_loss.upper)


def test_known_value_is_the_constant_leakage_at_rate_c_wl_u():
    """u = 4 m s-1, C_wl = 1e-4: the III.19 leakage with C_loss = 4e-4 m s-1; no wind, no flux."""
    rho = 1.2
    x = {"t_out": np.array([5.0, 5.0]), "wind": np.array([4.0, 0.0])}
    t_in = np.array([[15.0, 15.0]])
    q = WindLeakage(rho).flux({"c_wl": np.array([[1e-4]])}, x, t_in, slice(0, 2))
    np.testing.assert_allclose(q[0, 0], -1e-4 * rho * 4.0 * 10.0, rtol=1e-12)
    leak = AirLeakage(rho).flux({"c_loss": np.array([[4e-4]])}, x, t_in, slice(0, 2))
    np.testing.assert_allclose(q[0, 0], leak[0, 0], rtol=1e-12)
    assert q[0, 1] == 0.0


def test_slope_is_minus_the_derivative_of_the_flux_over_a_population():
    rng = np.random.default_rng(5)
    term = WindLeakage(1.2)
    x = {"t_out": rng.uniform(-5.0, 25.0, 100), "wind": rng.uniform(0.0, 12.0, 100)}
    p = {"c_wl": rng.uniform(0.0, C_WL_MAX, (3, 1))}
    state = rng.uniform(0.0, 30.0, (3, 100))
    t = slice(0, 100)
    g, s, k = term.linearised(p, x, state, t)
    h = 1e-4
    num = -(term.flux(p, x, state + h, t) - term.flux(p, x, state - h, t)) / (2 * h)
    np.testing.assert_allclose(k, num, rtol=1e-7)
    np.testing.assert_allclose(k, s, rtol=0)
    assert g.shape == s.shape == (3, 100)


def test_zero_gain_changes_nothing_and_a_gain_cools_a_windy_warm_house(weather_minutes,
                                                                       prototype_gh):
    gh = prototype_gh
    x = prepare_drivers(almeria_like_series(weather_minutes, days=1), gh)
    plain = structure(build_prototype(gh), gh, store=False)
    model = plain.with_terms(WindLeakage(gh.air_density))
    assert sorted(model.names) == sorted([*plain.names, "c_wl"])
    theta = model.defaults(gh)
    starts = np.arange(0, 1200, 7)
    runs = []
    for c_wl in (0.0, 2e-4):
        theta[model.index("c_wl")] = c_wl
        runs.append(model.forecast(np.repeat(theta[None, :], len(starts), 0), x, gh, 60.0, starts, 30))
    same = theta[[model.index(nm) for nm in plain.names]]
    ref = plain.forecast(np.repeat(same[None, :], len(starts), 0), x, gh, 60.0, starts, 30)
    np.testing.assert_allclose(runs[0], ref, rtol=0, atol=1e-9)
    end = starts + 30
    warm = (runs[0] > x["t_out"][end] + 2.0) & (x["wind"][starts] > 0.5)  # warm all the way
    assert warm.sum() > 10
    assert np.all(runs[1][warm] < runs[0][warm])
    assert np.mean(runs[0][warm] - runs[1][warm]) > 0.02

"""A thermostat-run heater the kit does not see (gateway/model/heating_control.py): units, bounds,
a known value, and the heated prototype holding a cold night's air (its exact slope:
tests/test_model.py, every term of every model)."""

import numpy as np
import pytest
from conftest import almeria_like_series

from gateway.model import HEATED_PROTOTYPE, VENTED_PROTOTYPE, build_model
from gateway.model.drivers import prepare_drivers
from gateway.model.heating_control import HeatingControl
from gateway.model.prototype import build_prototype
from gateway.model.vent_control import soft_excess


def test_parameters_units_bounds_and_an_always_active_search():
    c_hc, t_hs = HeatingControl().parameters
    assert (c_hc.name, c_hc.unit.split()[0], c_hc.lower, c_hc.upper) == ("c_hc", "kg", 0.0, 0.2)
    assert (t_hs.name, t_hs.unit, t_hs.lower, t_hs.upper) == ("t_hs", "°C", 0.0, 25.0)
    assert c_hc.active.name == t_hs.active.name == "always"
    assert HeatingControl().requires == ()


def test_known_value_below_and_above_the_setpoint():
    """3 K below T_hs = 12 °C: Q ≈ C_hc × 3 K (60 W m-2 K-1 / C_a gives 180 W m-2 / C_a); 5 K
    above it the heater is off."""
    c_hc = 60.0 / 1006.0  # 60 W m-2 K-1 in the lumped units (÷ C_a [J kg-1 K-1])
    p = {"c_hc": np.array([[c_hc]]), "t_hs": np.array([[12.0]])}
    x = {"t_out": np.array([0.0])}
    q = HeatingControl().flux(p, x, np.array([[9.0]]), 0)
    np.testing.assert_allclose(q, c_hc * float(soft_excess(np.array(3.0))), rtol=1e-12)
    np.testing.assert_allclose(q * 1006.0, 180.0, rtol=1e-3)
    off = HeatingControl().flux(p, x, np.array([[17.0]]), 0)
    assert 0.0 <= float(off[0, 0]) < 1e-4 * float(q[0, 0])


def test_the_model_name_builds_the_vented_prototype_plus_the_heater(prototype_gh):
    heated, vented = build_model(HEATED_PROTOTYPE, prototype_gh), build_model(VENTED_PROTOTYPE,
                                                                              prototype_gh)
    assert heated.name == HEATED_PROTOTYPE
    assert heated.names == [*vented.names, "c_hc", "t_hs"]
    with pytest.raises(ValueError, match="vented"):
        build_prototype(prototype_gh, heating=True)


@pytest.fixture(scope="module")
def with_term(weather_minutes, prototype_gh):
    series = almeria_like_series(weather_minutes, days=1)
    return build_model(HEATED_PROTOTYPE, prototype_gh), prepare_drivers(series, prototype_gh)


def test_zero_gain_is_the_vented_prototype(with_term, prototype_gh):
    model, x = with_term
    vented = build_model(VENTED_PROTOTYPE, prototype_gh)
    theta = model.defaults(prototype_gh)
    theta[model.index("c_hc")] = 0.0
    starts = np.arange(0, 1200, 7)
    got = model.forecast(np.repeat(theta[None, :], len(starts), 0), x, prototype_gh, 60.0, starts, 30)
    ref = vented.forecast(np.repeat(theta[None, :6], len(starts), 0), x, prototype_gh, 60.0,
                          starts, 30)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)


def test_a_heater_holds_a_cold_forecast_near_its_setpoint(with_term, prototype_gh):
    """A setpoint above every night forecast of the unheated house: with a strong heater the
    hour-ahead air ends within a kelvin of the setpoint; without it, well below."""
    model, x = with_term
    theta = model.defaults(prototype_gh)
    starts = np.arange(0, 1370, 11)
    night = np.array([np.all(x["i_glob"][s:s + 61] <= 5.0) for s in starts])
    assert night.sum() > 10
    runs = []
    for c_hc in (0.0, 0.2):
        theta[model.index("c_hc")] = c_hc
        theta[model.index("t_hs")] = 25.0
        runs.append(model.forecast(np.repeat(theta[None, :], len(starts), 0), x, prototype_gh,
                                   60.0, starts, 60)[night])
    assert np.all(runs[0] < 24.0)
    assert np.all(np.abs(runs[1] - 25.0) < 1.0)

"""Psychrometrics against published reference values, not against our own formulas."""

import numpy as np
import pytest

from gateway.model import psychrometrics as psy

# ASHRAE Handbook Fundamentals (2017) ch. 1, table 3: saturation pressure over water [kPa].
ASHRAE_PWS = [(0.0, 0.6112), (10.0, 1.2282), (20.0, 2.3393), (30.0, 4.2470), (40.0, 7.3851)]
# ASHRAE table 2: humidity ratio of saturated air at 101.325 kPa [kg kg-1].
ASHRAE_WS = [(10.0, 0.007661), (20.0, 0.014758), (30.0, 0.027329)]


@pytest.mark.parametrize(("t", "p_ws"), ASHRAE_PWS)
def test_saturation_vapour_pressure_matches_ashrae(t, p_ws):
    # Tetens is a fit: within 0.2 % of ASHRAE over 0–40 °C (Murray 1967).
    assert psy.saturation_vapour_pressure(t) == pytest.approx(p_ws, rel=2e-3)


@pytest.mark.parametrize(("t", "w_s"), ASHRAE_WS)
def test_humidity_ratio_at_saturation_matches_ashrae(t, w_s):
    # ASHRAE includes the enhancement factor (~0.4 %), an ideal mixture does not.
    w = psy.humidity_ratio(psy.saturation_vapour_pressure(t), psy.P_ATM)
    assert w == pytest.approx(w_s, rel=8e-3)


def test_dry_air_density_at_20c_standard_pressure():
    # 1.2041 kg m-3 at 20 °C, 101.325 kPa (ISO 2533 / standard tables).
    assert psy.moist_air_density(20.0, 0.0, 101.325) == pytest.approx(1.2041, rel=5e-4)


def test_moist_air_is_lighter_than_dry_air():
    p_w = psy.vapour_pressure(30.0, 80.0)
    assert psy.moist_air_density(30.0, p_w) < psy.moist_air_density(30.0, 0.0)


def test_vpd_at_25c_50_percent():
    # p_ws(25 °C) = 3.1699 kPa (ASHRAE): VPD at 50 % is half of it.
    assert psy.vapour_pressure_deficit(25.0, 50.0) == pytest.approx(3.1699 / 2, rel=2e-3)


def test_relative_humidity_inverts_vapour_pressure():
    t = np.array([5.0, 18.0, 33.0])
    rh = np.array([30.0, 65.0, 99.0])
    assert psy.relative_humidity(t, psy.vapour_pressure(t, rh)) == pytest.approx(rh)


@pytest.mark.parametrize("t_air_k", [263.15, 283.15, 303.15])
def test_swinbank_sky_temperature_matches_published_emission(t_air_k):
    # Swinbank (1963) published the clear-sky long-wave emission as 5.31e-13 T^6 W m-2.
    sigma = 5.670374e-8
    t_sky = psy.sky_temperature_k(t_air_k - psy.KELVIN)
    assert sigma * t_sky**4 == pytest.approx(5.31e-13 * t_air_k**6, rel=1.5e-2)


def test_latent_heat_at_20c_matches_steam_tables():
    # 2453.5 kJ kg-1 at 20 °C (IAPWS steam tables, as in ASHRAE table 3).
    assert psy.latent_heat_vaporisation(20.0) == pytest.approx(2453.5e3, rel=2e-3)


def test_saturation_vapour_pressure_slope_is_the_derivative():
    t = np.linspace(-10.0, 45.0, 12)
    h = 1e-5
    num = (psy.saturation_vapour_pressure(t + h) - psy.saturation_vapour_pressure(t - h)) / (2 * h)
    np.testing.assert_allclose(psy.saturation_vapour_pressure_slope(t), num, rtol=1e-8)
    # 0.1448 kPa/K at 20 °C (FAO-56 eq. 13 gives 0.1447 with its rounder constants)
    assert float(psy.saturation_vapour_pressure_slope(20.0)) == pytest.approx(0.1448, abs=2e-4)

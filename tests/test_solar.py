"""Solar position and clear-sky radiation against published values."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.greenhouse import GreenhouseError, load_greenhouse, parse_greenhouse
from gateway.model.solar import clear_sky_global, clear_sky_index, solar_position


def _at(stamp: str) -> np.ndarray:
    return np.array([stamp], dtype="datetime64[s]")


def test_nrel_spa_example() -> None:
    # Reda & Andreas (2004), NREL/TP-560-34302, table A4.1: 2003-10-17 12:30:30 at UTC-7,
    # 39.742476 N 105.1786 W: topocentric zenith 50.11162 deg including 0.0166 deg of
    # atmospheric refraction (820 mbar, 11 °C), so 50.128 deg without it.
    pos = solar_position(_at("2003-10-17T19:30:30"), 39.742476, -105.1786)
    assert pos.zenith[0] == pytest.approx(50.11162 + 0.0166, abs=0.01)
    assert pos.declination[0] == pytest.approx(-9.31434, abs=0.01)  # SPA geocentric delta


@pytest.mark.parametrize(
    ("stamp", "eot_min", "decl_deg"),
    [
        # Equation of time extremes and solstice/equinox declinations (Astronomical Almanac).
        ("2024-11-03T12:00:00", 16.4, -15.3),
        ("2024-02-11T12:00:00", -14.2, -14.1),
        ("2024-06-20T20:51:00", -1.8, 23.44),
        ("2024-03-20T03:06:00", -7.4, 0.0),
    ],
)
def test_equation_of_time_and_declination(stamp: str, eot_min: float, decl_deg: float) -> None:
    pos = solar_position(_at(stamp), 0.0, 0.0)
    assert pos.equation_of_time[0] == pytest.approx(eot_min, abs=0.15)
    assert pos.declination[0] == pytest.approx(decl_deg, abs=0.05)


def test_perihelion_distance() -> None:
    pos = solar_position(_at("2024-01-03T00:39:00"), 0.0, 0.0)
    assert pos.distance[0] == pytest.approx(0.98331, abs=2e-4)


def test_solar_noon_at_the_equation_of_time() -> None:
    # Solar noon at longitude 0 falls at 12:00 UTC minus the equation of time.
    day = np.arange(np.datetime64("2024-11-03T11:30:00"), np.datetime64("2024-11-03T12:30:00"),
                    np.timedelta64(1, "s"))
    pos = solar_position(day, 45.0, 0.0)
    noon = day[np.argmin(np.abs(pos.hour_angle))]
    expected = np.datetime64("2024-11-03T12:00:00") - np.timedelta64(int(16.45 * 60), "s")
    assert abs((noon - expected).astype(int)) <= 5


def test_haurwitz_against_pvlib() -> None:
    # pvlib-python tests/test_clearsky.py::test_haurwitz (apparent elevations and expected GHI)
    elevation = np.array([-20, -0.05, -0.001, 5, 10, 30, 50, 90], dtype=float)
    expected = [0, 0, 0, 48.6298687941956, 135.741748091813, 487.894132885425,
                778.766689344363, 1035.09203253450]
    got = clear_sky_global(np.sin(np.radians(elevation)))
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-9)


def test_clear_sky_index_is_nan_at_night_and_one_under_a_clear_sky() -> None:
    t = np.arange(np.datetime64("2024-06-21T00:00:00"), np.datetime64("2024-06-22T00:00:00"),
                  np.timedelta64(600, "s"))
    clear = clear_sky_global(solar_position(t, 36.79, -2.72).cos_zenith)
    k = clear_sky_index(clear, t, 36.79, -2.72)
    assert np.isnan(k[0])  # midnight
    day = np.isfinite(k)
    assert day.sum() > 60
    np.testing.assert_allclose(k[day], 1.0)


def test_bad_site_is_refused() -> None:
    with pytest.raises(ValueError, match="latitude"):
        solar_position(_at("2024-01-01T00:00:00"), 91.0, 0.0)


def test_presets_carry_their_site() -> None:
    assert load_greenhouse("almeria-palmerillas").site.latitude == pytest.approx(36.79)
    assert load_greenhouse("biskra-prototype").site.longitude == pytest.approx(5.73)


def test_site_needs_latitude_and_longitude() -> None:
    raw = {"geometry": {"floor_area": 1.0, "volume": 1.0}, "site": {"latitude": 52.0}}
    with pytest.raises(GreenhouseError, match="site.longitude"):
        parse_greenhouse(raw, "gh.toml")
    raw["site"] = {"latitude": 52.0, "longitude": 200.0}
    with pytest.raises(GreenhouseError, match="site.longitude"):
        parse_greenhouse(raw, "gh.toml")
    assert parse_greenhouse({"geometry": {"floor_area": 1.0, "volume": 1.0}}).site is None

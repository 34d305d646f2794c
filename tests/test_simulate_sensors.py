"""Sensor models (quantisation, noise, failures) and the vent controller's hysteresis."""

from __future__ import annotations

import numpy as np
import pytest

from training.simulate import sensors
from training.simulate.control import VentController, backlash


def _readings(spec, true, seed=0):
    rng = np.random.default_rng(seed)
    cal = sensors.draw_calibration(spec, rng)
    return cal, sensors.measure(np.asarray(true, dtype=float), spec, cal, rng)


def test_dht22_temperature_quantised_noisy_and_failing():
    true = np.full(200_000, 20.03)
    cal, x = _readings(sensors.DHT22_T, true)
    ok = np.isfinite(x)
    assert abs(cal.bias) <= 0.5
    np.testing.assert_allclose(x[ok] * 10.0, np.round(x[ok] * 10.0), atol=1e-9)
    assert abs(np.mean(x[ok]) - (20.03 + cal.bias)) < 0.01
    assert 0.06 < np.std(x[ok]) < 0.12  # 0.08 noise plus 0.1 quantisation
    assert 0.002 < np.mean(~ok) < 0.004


def test_dht22_bias_distribution_within_spec():
    biases = [sensors.draw_calibration(sensors.DHT22_T, np.random.default_rng(s)).bias
              for s in range(300)]
    assert max(abs(b) for b in biases) <= 0.5
    assert 0.15 < np.std(biases) < 0.3


def test_bpw34_gain_and_resolution():
    true = np.linspace(0.0, 1000.0, 5001)
    cal, x = _readings(sensors.BPW34, true, seed=3)
    np.testing.assert_allclose(x / 9.6, np.round(x / 9.6), atol=1e-6)
    big = true > 300
    gain = np.median(x[big] / true[big])
    assert gain == pytest.approx(cal.gain, abs=0.01)
    gains = [sensors.draw_calibration(sensors.BPW34, np.random.default_rng(s)).gain
             for s in range(300)]
    assert 0.015 < np.std(gains) < 0.03


def test_anemometer_steps():
    _, x = _readings(sensors.DC_ANEMOMETER, np.linspace(0.0, 12.0, 1000), seed=1)
    steps = x / 0.47
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert x.min() >= 0.0


def test_professional_sensors_are_tighter():
    true = np.full(50_000, 15.0)
    _, kit = _readings(sensors.DHT22_T, true, seed=9)
    _, pro = _readings(sensors.HC2S3_T, true, seed=9)
    assert np.nanstd(pro) < 0.5 * np.nanstd(kit)
    assert np.all(np.isfinite(pro))


def test_backlash_hysteresis():
    # Setpoint 24 degC, band 4 K, hysteresis 1 K.
    assert backlash(0.0, 26.0, 24.0, 4.0, 1.0) == pytest.approx(50.0)  # opens rising
    assert backlash(50.0, 25.5, 24.0, 4.0, 1.0) == pytest.approx(50.0)  # holds in the band
    assert backlash(50.0, 25.0, 24.0, 4.0, 1.0) == pytest.approx(50.0)  # still holds
    assert backlash(50.0, 24.5, 24.0, 4.0, 1.0) == pytest.approx(37.5)  # closes 1 K lower
    assert backlash(0.0, 23.9, 24.0, 4.0, 1.0) == 0.0


def test_controller_roof_first_then_side_and_loop_of_hysteresis():
    ctrl = VentController(speed=1e6)  # instant motors: look at the static law only
    temps = np.concatenate([np.linspace(20, 32, 121), np.linspace(32, 20, 121)])
    roof = side = 0.0
    trace = []
    for t in temps:
        roof, side = ctrl.step(t, False, 0.0, roof, side, 60.0)
        trace.append((t, roof, side))
    trace = np.array(trace)
    up, down = trace[:121], trace[121:][::-1]
    # Roof opens at its setpoint, side vents only 2.5 K later.
    assert up[up[:, 0] <= 24.0, 1].max() == 0.0 and up[up[:, 0] >= 25.0, 1].min() > 0.0
    assert up[up[:, 0] <= 26.5, 2].max() == 0.0 and up[up[:, 0] >= 27.5, 2].min() > 0.0
    # On the way down each opening is at least that of the way up (hysteresis loop).
    assert np.all(down[:, 1] >= up[:, 1] - 1e-9) and np.any(down[:, 1] > up[:, 1] + 1.0)


def test_controller_motor_speed_rain_and_wind():
    ctrl = VentController()
    roof, side = ctrl.step(35.0, False, 0.0, 0.0, 0.0, 60.0)
    assert roof == pytest.approx(ctrl.speed * 60.0) and side == pytest.approx(roof)
    roof, side = ctrl.step(35.0, False, 1.0, 100.0, 100.0, 1e6)
    assert roof == 0.0 and side == 100.0  # rain closes the roof only
    roof, side = ctrl.step(35.0, True, 0.0, 100.0, 100.0, 1e6)
    assert roof == ctrl.wind_cap and side == ctrl.wind_cap


def test_wind_alarm_hysteresis():
    ctrl = VentController(wind_limit=10.0, wind_hysteresis=2.0)
    wind = np.array([5.0, 9.9, 10.5, 9.0, 8.5, 10.2, 7.9, 9.5])
    expected = [False, False, True, True, True, True, False, False]
    assert ctrl.storm(wind).tolist() == expected

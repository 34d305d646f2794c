"""Unit checks of the diagnosis building blocks: effect terms, sensor terms, residual tools."""

from __future__ import annotations

import numpy as np

from gateway.diagnose import residuals as res
from gateway.diagnose.effects import EFFECTS
from gateway.diagnose.fit import Shooting, drivers, scan_tau, window_starts
from gateway.diagnose.search import compose
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.series import Series


def _series(n=2880):
    t = np.arange(n) * 60
    day = (t % 86400) / 86400
    cols = {"t_out": 10 + 5 * np.sin(2 * np.pi * (day - 0.3)), "rh_out": np.full(n, 70.0),
            "i_glob": np.maximum(0, 600 * np.sin(2 * np.pi * (day - 0.25))), "wind": np.full(n, 2.0),
            "rh_in": np.full(n, 60.0), "t_in": np.full(n, 12.0)}
    return Series((np.datetime64("2020-01-01T00:00:00") + t.astype("timedelta64[s]")), 60.0, cols)


def test_capacity_change_equals_scaled_capacity():
    """thermal_mass with factor m from τ = 0 gives the same run as a capacity × m model."""
    gh = load_greenhouse("biskra-prototype")
    base = build_model("prototype", gh)
    s = _series()
    x = drivers(s, gh)
    m = compose(base, [EFFECTS["thermal_mass"]], gh, len(s), 60.0)
    th = m.defaults(gh)
    th[m.index("m_capacity")] = 3.0
    with_term = m.free_run(th[None], x, gh, 60.0)[0]
    from dataclasses import replace

    scaled = replace(base, capacity=lambda g: 3.0 * base.capacity(g))
    direct = scaled.free_run(base.defaults(gh)[None], x, gh, 60.0)[0]
    np.testing.assert_allclose(with_term, direct, atol=1e-9)


def test_sensor_drift_changes_reading_not_state():
    gh = load_greenhouse("biskra-prototype")
    base = build_model("prototype", gh)
    s = _series()
    x = drivers(s, gh)
    m = compose(base, [EFFECTS["sensor_drift"]], gh, len(s), 60.0)
    th = m.defaults(gh)
    th[m.index("a_drift")] = 1.0
    th[m.index("tau_sensor_drift")] = 1440
    run = m.free_run(th[None], x, gh, 60.0)[0]
    plain = base.free_run(base.defaults(gh)[None], x, gh, 60.0)[0]
    np.testing.assert_allclose(run[:1441], plain[:1441], atol=1e-9)
    np.testing.assert_allclose(run[-1] - plain[-1], 1.0 * 1439 / 1440, atol=1e-9)


def test_scan_recovers_step_time_and_amplitude():
    """Data made by the model itself with a 40 % solar drop at sample 2000 (09:20, in sunlight,
    where it is identifiable): the τ scan finds it."""
    gh = load_greenhouse("biskra-prototype")
    base = build_model("prototype", gh)
    s = _series()
    x = drivers(s, gh)
    e = EFFECTS["solar_gain_change"]
    m = compose(base, [e], gh, len(s), 60.0)
    th = m.defaults(gh)
    truth = th.copy()
    truth[m.index("d_solar")], truth[m.index("tau_solar_gain_change")] = -0.4, 2000
    x["t_in"] = m.free_run(truth[None], x, gh, 60.0)[0]
    shoot = Shooting(m, x, gh, 60.0, window_starts([(0, len(s))], 180), 180)
    sse0, _ = shoot.sse(th[None])
    sc = scan_tau(shoot, th, e, np.arange(0, len(s), 30, dtype=float), float(sse0[0]))
    assert abs(sc.taus[sc.best] - 2000) <= 30
    assert abs(sc.amps[sc.best] + 0.4) < 0.05


def test_change_point_and_hour_profile():
    rng = np.random.default_rng(0)
    v = np.concatenate([rng.normal(0, 1, 50), rng.normal(3, 1, 30)])
    k, t = res.change_point(v)
    assert 47 <= k <= 53 and t > 8
    time = np.datetime64("2020-01-01T00:00") + np.arange(2880).astype("timedelta64[m]")
    r = np.where((np.arange(2880) // 60) % 24 == 13, 1.0, 0.0)
    prof = res.hour_profile(time, r)
    assert prof[13] == 1.0 and np.nansum(prof) == 1.0
    acf = res.autocorrelation(np.sin(np.arange(2880) * 2 * np.pi / 1440), np.array([0, 720, 1440]))
    assert acf[0] == 1.0 and acf[1] < -0.4 and acf[2] > 0.4

"""The disturbance filter on the grey box: it recovers a known heating rate and its AR(1) decay,
filters the reading noise, is causal, and its forecast is the model's when there is nothing to
add."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway.estimate import disturbance as dist
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.model.drivers import prepare_drivers
from gateway.series import Series

GH = load_greenhouse("almeria-palmerillas")
MODEL = build_model("prototype", GH)
DT = 300.0
NOISE = dist.DisturbanceSettings().sigma_v


def _house(b_true: np.ndarray, seed: int = 0, days: float = 4.0):
    """Five-minute kit data made by the prototype model itself plus a heating rate ``b_true``
    [K s-1] it does not have, read with the DHT22's noise. Returns (x, theta, truth)."""
    rng = np.random.default_rng(seed)
    n = int(days * 288)
    hour = np.arange(n) * DT / 3600.0
    sun = np.clip(np.sin((hour % 24 - 6.0) / 12.0 * np.pi), 0.0, None)
    time = np.datetime64("2020-11-01T00:00:00", "s") + np.arange(n) * np.timedelta64(300, "s")
    cols = {"t_out": 10.0 + 4.0 * np.sin((hour % 24 - 9.0) / 24.0 * 2 * np.pi),
            "rh_out": np.full(n, 80.0), "rh_in": np.full(n, 85.0), "i_glob": 400.0 * sun,
            "wind": 2.0 + np.abs(rng.normal(0, 0.5, n)), "t_in": np.full(n, 12.0)}
    x = prepare_drivers(Series(time, DT, cols), GH)
    theta = np.repeat(MODEL.defaults(GH)[None, :], n, axis=0)
    p = MODEL.columns(theta[:1])
    c = MODEL.capacity(GH)
    truth = np.empty(n)
    truth[0] = 12.0
    for k in range(n - 1):
        step = MODEL.step(p, x, np.array([[truth[k]]]), k, c, DT)[0, 0]
        truth[k + 1] = step + DT * b_true[k]
    x["t_in"] = np.round(truth + rng.normal(0.0, 0.08, n), 1)
    return x, theta, truth


def test_settings_are_the_stated_scales_per_five_minutes():
    s = dist.DisturbanceSettings()
    rho, q_t, q_b, r = s.per_step(300.0)
    assert rho == pytest.approx(0.9) and q_t == pytest.approx(0.01) and r == pytest.approx(NOISE**2)
    assert (DT * DT * q_b) == pytest.approx(1e-3)  # in (K per step)²
    rho1, q_t1, _, _ = s.per_step(60.0)  # a 1-minute gateway: the same physics per second
    assert rho1**5 == pytest.approx(0.9) and q_t1 == pytest.approx(0.002)


CONSTANT = dist.DisturbanceSettings(tau_b=math.inf)
"""A disturbance that never decays (ρ = 1, no process noise on b): a bias estimated by the
filter as recursive least squares would."""


def test_recovers_a_constant_heating_rate_and_filters_the_noise():
    b0 = 1.5e-4  # [K s-1]: 0.54 K h-1 the model does not know
    x, theta, truth = _house(np.full(4 * 288, b0))
    late = slice(288, None)
    f = dist.filter_series(MODEL, theta, x, GH, DT, CONSTANT)
    assert np.mean(f.b_hat[late]) == pytest.approx(b0, rel=0.05)
    # the default AR(1) disturbance (ρ = 0.9 per 5 min) takes up most of a bias that lasts
    f = dist.filter_series(MODEL, theta, x, GH, DT)
    assert 0.5 * b0 < np.mean(f.b_hat[late]) < b0
    raw = np.sqrt(np.nanmean((x["t_in"][late] - truth[late]) ** 2))
    filtered = np.sqrt(np.mean((f.t_hat[late] - truth[late]) ** 2))
    assert filtered < 0.8 * raw  # the start state is cleaner than the reading


def test_recovers_the_ar1_decay_of_a_disturbance():
    """A heat pulse that switches off: b̂ follows it and then decays back to ~0."""
    n = 4 * 288
    b_true = np.where((np.arange(n) >= 400) & (np.arange(n) < 600), 3e-4, 0.0)
    x, theta, truth = _house(b_true, seed=1)
    f = dist.filter_series(MODEL, theta, x, GH, DT)
    assert 0.5 * 3e-4 < np.mean(f.b_hat[500:600]) < 3e-4
    assert abs(np.mean(f.b_hat[700:])) < 3e-5
    assert abs(np.mean(f.b_hat[:400])) < 3e-5


def test_forecast_with_the_disturbance_beats_the_plain_model_and_equals_it_without():
    b0 = 1.5e-4
    x, theta, truth = _house(np.full(4 * 288, b0), seed=2)
    starts = np.arange(300, 4 * 288 - 12)
    h = 12
    plain = MODEL.forecast(theta[starts], x, GH, DT, starts, h)
    target = truth[starts + h]
    for settings, gain in ((None, 0.8), (CONSTANT, 0.3)):
        f = dist.filter_series(MODEL, theta, x, GH, DT, settings)
        kf = dist.forecast(MODEL, theta[starts], x, GH, DT, starts, h, f.t_hat[starts],
                           f.b_hat[starts], settings)
        assert np.mean(np.abs(kf - target)) < gain * np.mean(np.abs(plain - target))
    same = dist.forecast(MODEL, theta[starts], x, GH, DT, starts, h, x["t_in"][starts],
                         np.zeros(len(starts)))
    ok = np.isfinite(plain)
    np.testing.assert_allclose(same[ok], plain[ok], rtol=0, atol=1e-9)


def test_the_filter_is_causal():
    x, theta, _ = _house(np.full(2 * 288, 1e-4), seed=3, days=2.0)
    a = dist.filter_series(MODEL, theta, x, GH, DT)
    cut = 300
    y = {k: v.copy() for k, v in x.items()}
    y["t_in"][cut + 1:] += 5.0
    y["i_glob"][cut + 1:] = 0.0
    b = dist.filter_series(MODEL, theta, y, GH, DT)
    np.testing.assert_array_equal(a.t_hat[: cut + 1], b.t_hat[: cut + 1])
    np.testing.assert_array_equal(a.b_hat[: cut + 1], b.b_hat[: cut + 1])
    assert not math.isclose(a.t_hat[cut + 2], b.t_hat[cut + 2])


def test_gaps_dead_reckon_and_missing_parameters_wait():
    x, theta, _ = _house(np.zeros(2 * 288), seed=4, days=2.0)
    x["t_in"][100:110] = np.nan  # a hole in the readings: time updates only
    theta = theta.copy()
    theta[:5] = np.nan  # no parameters yet: no step, the filter restarts at the readings
    f = dist.filter_series(MODEL, theta, x, GH, DT)
    assert np.all(np.isfinite(f.t_hat)) and np.all(np.isfinite(f.b_hat))
    assert f.t_hat[0] == x["t_in"][0]
    none = dist.filter_series(MODEL, np.full_like(theta, np.nan), x, GH, DT)
    assert np.all(np.isnan(none.t_hat))


def test_the_live_filter_sample_by_sample_is_the_series_filter_and_resumes_exactly():
    x, theta, _ = _house(np.full(288, 1e-4), seed=5, days=1.0)
    x["t_in"][50:53] = np.nan
    theta = theta * np.linspace(0.9, 1.1, 288)[:, None]  # parameters that move, as online
    whole = dist.filter_series(MODEL, theta, x, GH, DT)
    live = dist.LiveFilter(MODEL, GH, DT)
    got = []
    for t in range(288):
        if t == 150:  # a restart of the gateway: the state goes through JSON
            import json

            snap = json.loads(json.dumps(live.snapshot()))
            live = dist.LiveFilter(MODEL, GH, DT)
            live.restore(snap)
        live.update({k: float(v[t]) for k, v in x.items()}, theta[t])
        got.append(live.estimate())
    np.testing.assert_allclose([g[0] for g in got], whole.t_hat, rtol=0, atol=1e-9)
    np.testing.assert_allclose([g[1] for g in got], whole.b_hat, rtol=0, atol=1e-12)
    live.reset()
    assert live.estimate() is None

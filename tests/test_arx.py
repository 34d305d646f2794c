"""The RLS ARX baseline: identification, causality, gaps, vectorised forecasts."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.estimate.arx import FORGETTING, REGRESSORS, ArxResult, Rls, exchange, fit, regressors
from gateway.model.drivers import prepare_drivers
from gateway.series import Series

THETA = np.array([4e-4, 0.05, 0.004, 0.01, 0.02])  # per K / W m-2 per step


def _drivers(n: int = 2000, seed: int = 0, noise: float = 0.0) -> dict[str, np.ndarray]:
    """Weather-like inputs and a T_in that follows the ARX law exactly (plus noise)."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    x = {
        "t_out": 8 + 4 * np.sin(2 * np.pi * k / 288) + rng.normal(0, 0.3, n),
        "i_glob": np.maximum(0, 400 * np.sin(2 * np.pi * (k - 72) / 288)) * rng.uniform(0.5, 1, n),
        "wind": np.abs(3 + rng.normal(0, 1.5, n)),
    }
    x["t_sky"] = x["t_out"] - 15 + rng.normal(0, 2, n)
    t = np.empty(n)
    t[0] = 12.0
    for i in range(n - 1):
        phi = regressors(x, np.array(t[i]), i)
        t[i + 1] = t[i] + phi @ THETA + rng.normal(0, noise)
    x["t_in"] = t
    return x


def test_the_issue_baseline_settings():
    assert FORGETTING == 0.995
    assert REGRESSORS == ("i_glob", "t_out - t_in", "wind (t_out - t_in)", "t_sky - t_in", "1")


def test_recovers_the_parameters_of_an_exact_arx_system():
    x = _drivers(noise=1e-3)
    res = fit(x)
    np.testing.assert_allclose(res.theta[-1], THETA, rtol=0.05, atol=2e-4)
    err = np.abs(res.one_step[500:] - x["t_in"][500:])
    assert np.mean(err) < 2e-3  # the noise level
    assert res.updates == len(x["t_in"]) - 1


def test_parameters_at_t_ignore_everything_after_t():
    x = _drivers()
    a = fit(x)
    y = {k: v.copy() for k, v in x.items()}
    y["t_in"][1001:] += 5.0
    y["i_glob"][1001:] = 0.0
    b = fit(y)
    np.testing.assert_array_equal(a.theta[:1001], b.theta[:1001])  # theta[1000] used T_in[<= 1000]
    assert not np.allclose(a.theta[1002], b.theta[1002])


def test_gaps_hold_the_parameters_and_skip_predictions():
    x = _drivers()
    x["t_in"][700:710] = np.nan
    x["wind"][900] = np.nan
    res = fit(x)
    assert np.all(np.isfinite(res.theta[1:]))
    np.testing.assert_array_equal(res.theta[699], res.theta[710])  # pairs 699..709 need a NaN
    assert np.isnan(res.one_step[701]) and np.isnan(res.one_step[901])


def test_forecast_is_a_vectorised_recursion():
    x = _drivers(noise=0.01)
    res = fit(x)
    starts = np.array([300, 777, 1500])
    h = 12
    got = res.forecast(x, starts, h)
    for s, g in zip(starts, got, strict=True):
        t = x["t_in"][s]
        for k in range(h):
            t = t + regressors(x, np.array(t), s + k) @ res.theta[s]
        assert g == pytest.approx(float(t), abs=1e-12)
    # driver blocks of their own (gateway/estimate/horizon.py): rows differ from the starts
    rows = np.array([0, 13, 26])
    block = {k: np.concatenate([v[s:s + h + 1] for s in starts]) for k, v in x.items()}
    np.testing.assert_allclose(res.forecast(block, starts, h, rows), got, atol=1e-12)


def _unguarded(x: dict[str, np.ndarray], theta: np.ndarray, h: int) -> np.ndarray:
    """T_in[h] from T_in[0] by the plain recursion T + θ · φ(T), one θ per row of ``theta``."""
    t = np.full(len(theta), x["t_in"][0])
    for k in range(h):
        t = t + np.einsum("nj,nj->n", regressors(x, t, k), theta)
    return t


def test_forecast_guard_keeps_the_coefficient_on_t_in_physical():
    """The recursion's multiplier on T_in is 1 − c, c = θ₂ + θ₃ u + θ₄. Poorly excited RLS
    parameters can leave 0 ≤ c ≤ 1; the plain 60-step recursion then amplifies (c < 0) or
    oscillates with growing amplitude (c > 1). The forecast clips c to [0, 1] about the start's
    temperature: the same numbers where c is in range, bounded where not."""
    h = 60
    x = {"t_out": np.full(h + 1, 10.0), "t_sky": np.full(h + 1, -5.0),
         "i_glob": np.full(h + 1, 300.0), "wind": np.full(h + 1, 2.0),
         "t_in": np.full(h + 1, 20.0)}
    theta = np.array([
        [4e-4, 0.02, 0.005, 0.01, 0.01],   # c = 0.04: stable, in range
        [4e-4, -0.30, 0.0, 0.01, 0.0],     # c = -0.29: multiplier 1.29, amplifies
        [4e-4, 2.0, 0.0, 0.5, 0.0],        # c = 2.5: multiplier -1.5, oscillates and grows
        [0.0, 1.0, 0.0, 0.0, 0.0],         # c = 1: the edge, in range (lands on T_out)
        [0.0, 0.0, 0.0, 0.0, 0.0],         # c = 0: the other edge, in range (no exchange)
    ])
    c = exchange(theta, 2.0)
    np.testing.assert_allclose(c, [0.04, -0.29, 2.5, 1.0, 0.0])
    res = ArxResult(theta=theta, one_step=np.zeros(0), updates=1)
    starts = np.arange(len(theta))
    rows = np.zeros(len(theta), dtype=int)
    plain = _unguarded(x, theta, h)
    got = res.forecast(x, starts, h, rows)
    assert np.all(np.abs(plain[1:3] - 20.0) > 1e5)  # the unguarded recursion runs away
    inside = np.array([True, False, False, True, True])
    np.testing.assert_array_equal(got[inside], plain[inside])  # the same numbers, bit for bit
    # outside the range, the fitted step at the start's 20 °C and c* = 0 or 1 about it:
    step0 = np.einsum("nj,nj->n", regressors(x, x["t_in"][rows], 0), theta)
    assert got[1] == pytest.approx(20.0 + h * step0[1])  # c* = 0: the start's step, every step
    assert got[2] == pytest.approx(20.0 + step0[2])  # c* = 1: each step from the start's point
    # the first step is the fitted one-step prediction, guarded or not
    np.testing.assert_array_equal(res.forecast(x, starts, 1, rows), _unguarded(x, theta, 1))
    assert np.all(np.abs(got - 20.0) < 200.0)


def test_forecast_guard_is_per_step_with_the_wind():
    """c depends on the wind of each step: a θ₃ < 0 that is harmless in a breeze (c > 0) turns
    the exchange around in a gale; only those steps are clipped."""
    h = 30
    wind = np.where(np.arange(h + 1) < 10, 1.0, 12.0)
    x = {"t_out": np.full(h + 1, 5.0), "t_sky": np.full(h + 1, -10.0),
         "i_glob": np.zeros(h + 1), "wind": wind, "t_in": np.full(h + 1, 18.0)}
    theta = np.array([[0.0, 0.05, -0.01, 0.02, 0.0]])  # c = 0.06 at 1 m/s, -0.05 at 12 m/s
    res = ArxResult(theta=theta, one_step=np.zeros(0), updates=1)
    np.testing.assert_array_equal(res.forecast(x, np.array([0]), 10, np.array([0])),
                                  _unguarded(x, theta, 10))
    plain, got = _unguarded(x, theta, h), res.forecast(x, np.array([0]), h, np.array([0]))
    t10 = float(_unguarded(x, theta, 10)[0])
    step = float((regressors(x, np.array([18.0]), 10) @ theta[0])[0])  # the fitted step at 18 °C
    assert got[0] == pytest.approx(t10 + (h - 10) * step)  # c* = 0 from step 10 on
    assert got[0] != plain[0]


def _one_minute_greenhouse(weather: dict[str, np.ndarray], gh, days: int = 5) -> dict[str, np.ndarray]:
    """A first-order greenhouse air balance on the shipped Bleiswijk weather at 1-minute steps,
    read by a 0.1 K sensor: C dT/dt = 0.5 I_glob + (U (1 + 4 vent) + 0.8 u)(T_out - T)
    + 1.5 (T_sky - T) [W m-2], vents opening from 25 °C (a nonlinearity the ARX does not have)."""
    a, n = 60, days * 1440
    cols = {k: weather[k][a:a + n].copy() for k in ("t_out", "rh_out", "i_glob", "wind")}
    series = Series(weather["time"][a:a + n], 60.0, {**cols, "t_in": cols["t_out"]}, source="1-min")
    x = prepare_drivers(series, gh)
    c = 3e4  # air and fast thermal mass [J m-2 K-1]
    t = np.empty(n)
    t[0] = cols["t_out"][0] + 3.0
    for i in range(n - 1):
        vent = 1.0 + 4.0 * np.clip((t[i] - 25.0) / 5.0, 0.0, 1.0)
        q = (0.5 * x["i_glob"][i] + (4.0 * vent + 0.8 * x["wind"][i]) * (x["t_out"][i] - t[i])
             + 1.5 * (x["t_sky"][i] - t[i]))
        t[i + 1] = t[i] + 60.0 * q / c
    x["t_in"] = np.round(t, 1)  # DHT22 resolution
    return x


def test_stays_finite_and_useful_on_one_minute_data(weather_minutes, almeria_gh):
    """At 1-minute steps λ = 0.995 per sample is a 3-hour memory in which T_out - T_in and
    T_sky - T_in are nearly collinear: P grows ill-conditioned, and the conventional update lost
    its symmetry and positive definiteness by rounding, after which θ and the 60-step forecasts
    ran to 1e68 here (and 1e50 in the 15-day replay). P must stay symmetric PSD, and the
    forecasts must beat persistence."""
    x = _one_minute_greenhouse(weather_minutes, almeria_gh)
    n = len(x["t_in"])
    rls = Rls()
    phi = regressors(x, x["t_in"], slice(0, n))
    for t in range(n - 1):
        rls.update(phi[t], x["t_in"][t + 1] - x["t_in"][t])
        if t % 240 == 0:
            np.testing.assert_array_equal(rls.p, rls.p.T)
            assert np.linalg.eigvalsh(rls.p)[0] > -1e-9 * np.trace(rls.p)
    res = fit(x)
    starts = np.arange(1440, n - 60)  # after a day of learning
    for h in (15, 60):
        f = res.forecast(x, starts, h)
        truth = x["t_in"][starts + h]
        assert np.all(np.isfinite(f)) and np.all(np.abs(f - truth) < 20.0)
        persistence = np.mean(np.abs(x["t_in"][starts] - truth))
        assert np.mean(np.abs(f - truth)) < 0.7 * persistence


def test_restore_drops_a_covariance_that_is_not_positive_definite():
    """A state saved by the conventional update (before the symmetric one) may hold a P with a
    negative eigenvalue; learning on from it would diverge, so the estimator starts afresh."""
    rls = Rls()
    bad = np.diag([1.0, 1.0, -1.0, 1.0, 1.0])
    rls.restore({"w": [1e6] * 5, "p": bad.tolist(), "updates": 9000})
    assert rls.updates == 0 and np.all(np.isnan(rls.theta))
    np.testing.assert_array_equal(rls.p, Rls().p)
    good = Rls()
    good.update(np.array([200.0, 3.0, 6.0, -10.0, 1.0]), 0.05)
    fresh = Rls()
    fresh.restore(good.snapshot())
    np.testing.assert_array_equal(fresh.theta, good.theta)

"""The RLS ARX baseline: identification, causality, gaps, vectorised forecasts."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.estimate.arx import FORGETTING, REGRESSORS, fit, regressors

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

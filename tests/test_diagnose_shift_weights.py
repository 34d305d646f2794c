"""Covariate-shift weights of the base calibration (gateway/diagnose/shift_weights.py,
base.SHIFT_WEIGHTS; issue 10, cw)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import base
from gateway.diagnose.fit import Shooting, drivers, window_starts
from gateway.diagnose.shift_weights import CLIP, ShiftRatio, fit_ratio, logistic_l2, shift_weights
from tests.diagnose_data import prototype_bases, sine_series

H = 72  # 6 h of 5-minute rows
N, S = 2304, 1152  # 8 days, split after 4: both parts' windows start at the same clock times


def weather(hot_from: int | None = None, hot_k: float = 8.0) -> dict[str, np.ndarray]:
    """Kit drivers of 8 days of sine weather; from row ``hot_from`` on, T_out + ``hot_k``."""
    gh, _, _ = prototype_bases()
    s = sine_series(n=N, step=300)
    if hot_from is not None:
        s.columns["t_out"][hot_from:] += hot_k
    return drivers(s, gh)


def fit_windows() -> np.ndarray:
    return window_starts([(0, S)], H, skip=H)


def test_identical_weather_in_both_parts_gives_weights_of_one():
    x = weather()
    w = shift_weights(fit_ratio(x, S, H), x, fit_windows(), H)
    np.testing.assert_allclose(w, 1.0, atol=1e-6)


def test_a_hotter_held_out_part_up_weights_the_hot_calibration_windows():
    """Calibration: 2.5 cool days then 1.5 hot ones; held-out: all hot. The hot calibration
    windows are like the held-out part's and weigh more than every cool one."""
    hot_from = 720
    x = weather(hot_from)
    starts = fit_windows()
    w = shift_weights(fit_ratio(x, S, H), x, starts, H)
    hot = starts >= hot_from
    assert hot.any() and (~hot).any()
    assert w[hot].min() > w[~hot].max()
    assert w.mean() == pytest.approx(1.0)


def test_weights_have_mean_one_and_stay_within_the_clip():
    """A ratio far beyond the clip at both ends: the weights' spread is the clip's, mean 1."""
    ratio = ShiftRatio(np.zeros(4), np.ones(4), np.array([0.0, 10.0, 0.0, 0.0, 0.0]), 1.0)
    z = np.column_stack([np.linspace(-2.0, 2.0, 9), np.zeros((9, 3))])
    w = ratio.weights(z)
    assert w.mean() == pytest.approx(1.0)
    assert w.max() / w.min() == pytest.approx(CLIP[1] / CLIP[0])
    x = weather(720)
    w = shift_weights(fit_ratio(x, S, H), x, fit_windows(), H)
    assert w.max() / w.min() <= CLIP[1] / CLIP[0] * (1 + 1e-12)


def test_the_inside_readings_are_never_read():
    """The held-out T_in and rh_in (indeed all inside readings) NaN or changed: same weights."""
    x = weather(720)
    want = shift_weights(fit_ratio(x, S, H), x, fit_windows(), H)
    blind = dict(x)
    for name in ("t_in", "rh_in", "p_w_in"):
        blind[name] = x[name].copy()
        blind[name][S:] = np.nan
    blind["t_in"][:S] = np.random.default_rng(3).normal(20.0, 5.0, S)
    got = shift_weights(fit_ratio(blind, S, H), blind, fit_windows(), H)
    np.testing.assert_array_equal(got, want)


def test_logistic_regression_solves_its_penalised_score_equations():
    """At the returned coefficients the gradient of log-loss + ||β||² / 2 (C = 1, intercept
    unpenalised) vanishes."""
    rng = np.random.default_rng(0)
    z = rng.normal(size=(60, 4))
    y = (z[:, 0] + rng.normal(size=60) > 0.3).astype(float)
    beta = logistic_l2(z, y)
    a = np.column_stack([np.ones(60), z])
    p = 1.0 / (1.0 + np.exp(-(a @ beta)))
    grad = a.T @ (p - y) + np.r_[0.0, beta[1:]]
    np.testing.assert_allclose(grad, 0.0, atol=1e-8)
    assert beta[1] > 0.5  # the informative feature


def calibrate(x: dict[str, np.ndarray], monkeypatch, weights=None) -> tuple[np.ndarray, list]:
    """calibrate_base on 7 days (fit 4.67, judge 2.33 of them) of ``x``, recording every
    Shooting's weights; ``weights``: a weigher put in place of the switch's."""
    gh, _, m = prototype_bases()
    seen: list = []

    class Spy(Shooting):
        def __post_init__(self) -> None:
            super().__post_init__()
            seen.append(self.weight)

    monkeypatch.setattr(base, "Shooting", Spy)
    if weights is not None:
        monkeypatch.setattr(base, "weigher", lambda x, s, horizon: weights)
    x = {k: v[:2016] for k, v in x.items()}
    _, theta, _ = base.calibrate_base(m, gh, x, 300.0, 1344, H, 0, lambda msg: None)
    return theta, seen


def test_switch_off_is_unweighted_and_equals_unit_weights(monkeypatch):
    """Off: every Shooting of the calibration is unweighted, and the result is exactly the one
    with all weights 1 (the weighted path adds nothing else)."""
    monkeypatch.setattr(base, "SHIFT_WEIGHTS", False)
    gh, _, m = prototype_bases()
    x = weather(720)
    x["t_in"] = m.free_run(m.defaults(gh)[None], x, gh, 300.0)[0] + 0.3 * np.sin(
        np.arange(N) / 50.0)
    off, seen = calibrate(x, monkeypatch)
    assert seen and all(w is None for w in seen)
    ones, seen1 = calibrate(x, monkeypatch, lambda starts: np.ones(len(starts)))
    assert all(w is not None for w in seen1)
    np.testing.assert_array_equal(off, ones)


def test_switch_on_weights_every_calibration_fit(monkeypatch):
    monkeypatch.setattr(base, "SHIFT_WEIGHTS", True)
    gh, _, m = prototype_bases()
    x = weather(720)
    x["t_in"] = m.free_run(m.defaults(gh)[None], x, gh, 300.0)[0]
    _, seen = calibrate(x, monkeypatch)
    assert seen and all(w is not None and w.mean() == pytest.approx(1.0) for w in seen)
    assert any(w.std() > 0.05 for w in seen)

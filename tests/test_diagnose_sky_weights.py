"""The base calibration's weights from the sky the kit cannot see (sky_weights.py, issue 10)."""

from __future__ import annotations

import numpy as np

from gateway.diagnose import base
from gateway.diagnose.fit import Shooting, drivers, window_starts
from gateway.diagnose.night_sky import LEVEL, RELAX, NightSky
from gateway.diagnose.sky_weights import sky_weights
from gateway.diagnose.structure import SkyLoss, model_unit
from tests.diagnose_data import prototype_bases, sine_series

N, H, DT = 2016, 72, 300.0  # 7 days of 5-min rows, 6 h windows


def _misread_night(night: int | None):
    """7 dull days (the kit reads cloud ≈ 0.9 and carries it into the night) from a house
    losing c_lw_sky = 5 W m-2 K-1 to the sky; on ``night`` (0-based, None: none) the true sky
    is clear (cloud 0.05), the kit's is not. T_in with 0.1 K of seeded noise. Returns (kit's
    drivers with T_in, true drivers, model, true parameters, fit start)."""
    gh, _, m = prototype_bases()
    s = sine_series(n=N, step=int(DT))
    s.columns["t_out"] = s.columns["t_out"] - 6.0
    s.columns["i_glob"] = 0.3 * s.columns["i_glob"]
    x = drivers(s, gh)
    plain = m.with_terms(SkyLoss(model_unit(m, gh)))
    truth = plain.defaults(gh)
    truth[plain.index("c_lw_sky")] = 5.0
    evening = (np.arange(N) * DT + 6 * 3600.0) // 86400  # night k: evening k to morning k + 1
    clear = NightSky().t_sky({LEVEL.name: np.array([[0.05]])}, x, slice(None))[0]
    true_x = dict(x)
    true_x["t_sky"] = np.where((evening == night) & (x[RELAX] > 0), clear, x["t_sky"])
    noise = np.random.default_rng(0).normal(0.0, 0.1, N)
    x["t_in"] = plain.free_run(truth[None], true_x, gh, DT)[0] + noise
    th0 = truth.copy()
    th0[plain.index("c_lw_sky")] = 2.0
    return gh, x, true_x, plain, truth, th0


def test_weights_are_lower_where_the_sky_weighs_more_and_average_one():
    """Mean 1 over the measured samples; a free run's end carries more of the sky's spread
    than its first step, and carried (night) rows more than read ones on average."""
    gh, x, _, plain, _, th0 = _misread_night(None)
    starts = window_starts([(0, N)], H, skip=H)
    w = sky_weights(plain, th0, x, gh, DT, starts, H)
    assert w.shape == (len(starts), H)
    np.testing.assert_allclose(w.mean(), 1.0, rtol=1e-12)
    assert np.all(w[:, -1] < w[:, 0])
    carried = x[RELAX][starts[:, None] + np.arange(1, H + 1)[None, :]] > 0
    assert w[carried].mean() < w[~carried].mean()


def test_switch_off_is_the_unweighted_calibration(monkeypatch):
    """Off (the default): no weights are computed and the residual is prediction minus
    measurement, as before; weights of 1 give the same cost."""
    gh, x, _, plain, _, th0 = _misread_night(None)
    assert base.SKY_WEIGHTS is False

    def refuse(*args, **kwargs):
        raise AssertionError("sky weights computed with the switch off")

    monkeypatch.setattr(base, "sky_weights", refuse)
    assert base.weigher(plain, th0, x, gh, DT, H)(np.array([100, 500])) is None
    starts = window_starts([(0, N)], H, skip=H)
    off = Shooting(plain, x, gh, DT, starts, H)
    assert off.weight is None
    np.testing.assert_array_equal(off.residual(th0[None]), off.predict(th0[None]) - off.target[None])
    ones = Shooting(plain, x, gh, DT, starts, H, np.ones((len(starts), H)))
    np.testing.assert_array_equal(ones.sse(th0[None])[0], off.sse(th0[None])[0])


def test_a_misread_night_pulls_the_weighted_fit_less():
    """One clear night the kit reads as overcast distorts the plain fit (the free run under
    the true sky drifts from the truth); weighted by the sky's spread the fit is pulled less.
    The gain is small (~7 %): the measured spread gives night weights only 12-33 % below the day's
    (docs/effects.md, "Weighting the base by the sky's spread")."""
    gh, x, true_x, plain, truth, th0 = _misread_night(1)
    starts = window_starts([(0, N)], H, skip=H)
    ref = plain.free_run(truth[None], true_x, gh, DT)[0]
    err = {}
    for weighted in (False, True):
        w = sky_weights(plain, th0, x, gh, DT, starts, H) if weighted else None
        th = base.fit(plain, th0, Shooting(plain, x, gh, DT, starts, H, w), gh, 40, 0)
        err[weighted] = float(np.mean(np.abs(plain.free_run(th[None], true_x, gh, DT)[0] - ref)))
    assert err[False] > 0.5  # the misread night distorts the plain fit
    assert err[True] < 0.95 * err[False], err


def test_the_calibration_weights_every_shooting_set_when_on(monkeypatch):
    """With ``base.SKY_WEIGHTS`` the base fit, the inner validation and the final refit each
    get weights, all from the start model and parameters (one yardstick)."""
    gh, x, _, _, _, _ = _misread_night(None)
    _, _, m = prototype_bases()
    seen: list[tuple[int, bytes, tuple[int, ...]]] = []
    real = base.sky_weights

    def spy(model, theta, *args):
        seen.append((id(model), theta.tobytes(), tuple(int(v) for v in args[-2])))
        return real(model, theta, *args)

    monkeypatch.setattr(base, "SKY_WEIGHTS", True)
    monkeypatch.setattr(base, "sky_weights", spy)
    base.calibrate_base(m, gh, x, DT, 1344, H, 0, lambda msg: None)
    assert len({s[:2] for s in seen}) == 1  # one start model and parameter set
    assert len({s[2] for s in seen}) == 3  # fit windows, validation windows, all of C

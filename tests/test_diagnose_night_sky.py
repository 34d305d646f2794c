"""The night sky level of the diagnosis's base (gateway/diagnose/night_sky.py, issue 10)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose.base import fit
from gateway.diagnose.fit import Shooting, drivers, window_starts
from gateway.diagnose.night_sky import LEVEL, PRIOR, RELAX, NightSky
from gateway.diagnose.structure import Modulation, SensorBias, SkyLoss, model_unit
from gateway.model.terms import ALWAYS, Parameter
from tests.diagnose_data import prototype_bases, sine_series


def test_level_at_the_prior_is_the_kits_sky_and_days_are_left_alone():
    """With the level equal to the kit's prior the sky is the kit's (sky.py); by day, where the
    cloud is read (r = 0), any level leaves it alone."""
    gh, _, _ = prototype_bases()
    x = drivers(sine_series(n=2016, step=300), gh)
    ns, t = NightSky(), slice(None)
    np.testing.assert_allclose(ns.t_sky({LEVEL.name: x[PRIOR][None, :]}, x, t)[0], x["t_sky"],
                               atol=1e-9)
    clear = ns.t_sky({LEVEL.name: np.zeros((1, 1))}, x, t)[0]
    read = x[RELAX] == 0.0
    assert read.any() and (~read).any()
    np.testing.assert_allclose(clear[read], x["t_sky"][read], atol=1e-9)
    assert np.all(clear[~read] <= x["t_sky"][~read] + 1e-9)


def _clear_nights(gh, m):
    """7 days of dull days (the kit reads cloud ≈ 0.9 and carries it into the night) and clear
    nights (true night cloud 0.05), from a house losing c_lw_sky = 5 W m-2 K-1 to the sky:
    (drivers with the kit's sky and the simulated T_in, the model, the true parameters)."""
    s = sine_series(n=2016, step=300)  # 7 days
    s.columns["t_out"] = s.columns["t_out"] - 6.0  # 4-14 °C outside
    s.columns["i_glob"] = 0.3 * s.columns["i_glob"]
    x = drivers(s, gh)
    assert x["cloud"][x[RELAX] > 0.5].mean() > 0.8  # the kit's night: overcast
    plain = m.with_terms(SkyLoss(model_unit(m, gh)))
    truth = plain.defaults(gh)
    truth[plain.index("c_lw_sky")] = 5.0
    true_x = dict(x)
    true_x["t_sky"] = NightSky().t_sky({LEVEL.name: np.array([[0.05]])}, x, slice(None))[0]
    x["t_in"] = plain.free_run(truth[None], true_x, gh, 300.0)[0]
    return x, plain, truth


def test_clear_nights_read_as_overcast_do_not_distort_the_sky_loss():
    """On :func:`_clear_nights`, fitted on the kit's sky, the loss rate c_lw_sky / m_cap (the
    identifiable quantity: fluxes and capacity scale together) is far from the truth; with the
    night level as a base parameter the level and the rate come back."""
    gh, _, m = prototype_bases()
    x, plain, truth = _clear_nights(gh, m)
    starts = window_starts([(0, 2016)], 72, skip=72)
    rate = {}
    for model in (plain, plain.with_night_sky()):
        th0 = model.defaults(gh)
        th0[: len(truth)] = truth
        th0[model.index("c_lw_sky")] = 2.0
        th = fit(model, th0, Shooting(model, x, gh, 300.0, starts, 72), gh, 40, 0)
        rate[model.night_sky is not None] = th[model.index("c_lw_sky")] / th[model.index("m_cap")]
        if model.night_sky is not None:
            assert abs(th[model.index(LEVEL.name)] - 0.05) < 0.05
    assert abs(rate[False] - 5.0) > 2.0, rate  # the misread nights distort the plain fit
    assert abs(rate[True] - 5.0) < 0.75, rate


def test_the_base_calibration_fits_the_night_level(monkeypatch):
    """With ``base.NIGHT_SKY_IN_BASE`` (off in the shipped choice, docs/effects.md "Base
    structure"), ``base.calibrate_base`` carries the level and finds the clear nights the kit
    read as overcast; without it the base has no level."""
    from gateway.diagnose import base

    gh, _, m = prototype_bases()
    x, _, _ = _clear_nights(gh, m)
    got, _, _ = base.calibrate_base(m, gh, x, 300.0, 1344, 72, 0, lambda msg: None)
    assert got.night_sky is None and LEVEL.name not in got.names
    monkeypatch.setattr(base, "NIGHT_SKY_IN_BASE", True)
    got, th, _ = base.calibrate_base(m, gh, x, 300.0, 1344, 72, 0, lambda msg: None)
    assert got.night_sky is not None
    assert th[got.index(LEVEL.name)] < 0.3


def test_shooting_sees_the_same_sky_as_the_step_by_step_run():
    """``shoot`` computes the fitted sky once for all windows (recomputed.windows); its runs
    are the free runs that compute it step by step, for every candidate level and window."""
    gh, _, m = prototype_bases()
    x, plain, truth = _clear_nights(gh, m)
    model = plain.with_night_sky()
    assert model.names[:-1] == plain.names  # the level last
    theta = np.repeat(model.defaults(gh)[None, :], 4, axis=0)
    theta[:, : len(truth)] = truth
    theta[:, model.index(LEVEL.name)] = [0.4, 0.0, 1.0, 0.4]  # one level twice
    starts, h = np.array([100, 700, 1500]), 72
    got = model.shoot(theta, x, gh, 300.0, starts, h)
    for i, s0 in enumerate(starts):
        run = model.free_run(theta, x, gh, 300.0, start=s0, stop=s0 + h + 1)
        np.testing.assert_array_equal(got[:, i, :], run[:, 1:])
    for row in theta:  # the plain model driven by each level's sky
        sky_x = dict(x)
        sky_x["t_sky"] = NightSky().t_sky({LEVEL.name: row[model.index(LEVEL.name)]}, x,
                                          slice(None))
        ref = plain.free_run(row[None, : len(plain.names)], sky_x, gh, 300.0)[0]
        np.testing.assert_allclose(model.free_run(row[None], x, gh, 300.0)[0], ref,
                                   rtol=0, atol=1e-12)
    assert np.ptp(got[:, :, -1], axis=0).max() > 0.1  # the level matters on these nights


def test_the_guard_narrows_the_levels_box_around_the_kits_prior(monkeypatch):
    """``base.NIGHT_SKY_WIDTH`` (None in the shipped choice: the whole 0..1) fits the level
    within ± the width of its start, the kit's mean prior, clipped to 0..1; the level's
    default stays inside its box."""
    from gateway.diagnose import base

    gh, _, m = prototype_bases()
    assert base.night_bounds(0.7) == (0.0, 1.0)
    monkeypatch.setattr(base, "NIGHT_SKY_WIDTH", 0.2)
    np.testing.assert_allclose(base.night_bounds(0.9), (0.7, 1.0))
    for prior in (0.05, 0.3, 0.95):  # the default 0.6 is outside the first and last box
        model = base.structure(m, gh, store=False).with_night_sky(*base.night_bounds(prior))
        lower, upper = model.bounds(gh)
        j = model.index(LEVEL.name)
        np.testing.assert_allclose((lower[j], upper[j]),
                                   (max(prior - 0.2, 0.0), min(prior + 0.2, 1.0)))
        assert lower[j] <= model.defaults(gh)[j] <= upper[j]


@pytest.mark.parametrize("name", [LEVEL.name, "b_sensor"])
def test_a_modulation_of_a_parameter_read_once_per_run_is_refused(name):
    """The fitted sky and the vapour pressure behind an electronic offset are computed once
    per run from the unmodulated parameters: a modulation of those parameters is an error
    naming both, in the free run and in shooting (not an assert, gone under ``python -O``)."""
    gh, _, m = prototype_bases()
    x = drivers(sine_series(n=600, step=300), gh)
    amp = Parameter("a_bad", "-", -1.0, 1.0, 0.0, None, ALWAYS, "relative change")
    tau = Parameter("tau_bad", "s", 0.0, 1e6, 0.0, None, ALWAYS, "start")
    model = m.with_night_sky().with_sensors(SensorBias())
    model = model.with_modulation(Modulation("bad", (name,), amp, tau, 0.0))
    theta = model.defaults(gh)[None, :]
    with pytest.raises(ValueError, match=f"'bad' changes the parameter '{name}'"):
        model.shoot(theta, x, gh, 300.0, np.array([10, 200]), 12)
    if name == LEVEL.name:  # the free run precomputes the sky only
        with pytest.raises(ValueError, match=f"'bad' changes the parameter '{name}'"):
            model.free_run(theta, x, gh, 300.0)

"""Flux-term models: vectorisation, exact integration, stability at the box corners."""

import itertools
from dataclasses import replace

import numpy as np
import pytest
from conftest import almeria_like_series

from gateway.model import build_model
from gateway.model.drivers import prepare_drivers, roof_vent_area, side_vent_area
from gateway.model.step import FROZEN


@pytest.fixture(scope="module")
def almeria(weather_minutes, almeria_gh):
    model = build_model("almeria", almeria_gh)
    series = almeria_like_series(weather_minutes, days=2)
    return model, prepare_drivers(series, almeria_gh), almeria_gh


@pytest.fixture(scope="module")
def prototype(weather_minutes, prototype_gh):
    model = build_model("prototype", prototype_gh)
    series = almeria_like_series(weather_minutes, days=2)
    return model, prepare_drivers(series, prototype_gh), prototype_gh


@pytest.fixture(scope="module")
def prototype_vc(weather_minutes, prototype_gh):
    """The prototype with controller-moved vents (gateway/model/vent_control.py)."""
    from gateway.model.prototype import build_prototype

    model = build_prototype(prototype_gh, vent_control=True)
    series = almeria_like_series(weather_minutes, days=2)
    return model, prepare_drivers(series, prototype_gh), prototype_gh


@pytest.fixture(scope="module")
def prototype_hc(prototype_vc):
    """The vented prototype with a thermostat-run heater (gateway/model/heating_control.py)."""
    from gateway.model.prototype import build_prototype

    _, x, gh = prototype_vc
    return build_prototype(gh, vent_control=True, heating=True), x, gh


def random_population(model, gh, n, seed=0):
    lo, hi = model.bounds(gh)
    return lo + np.random.default_rng(seed).random((n, len(lo))) * (hi - lo)


def test_almeria_has_the_ten_parameters_of_table_13(almeria):
    model, _, gh = almeria
    assert model.names == ["c_asw", "c_cnv_ss", "c_cnd_cnv", "c_a", "c_bd", "c_bn",
                           "c_ven_d", "c_ven_w", "c_loss", "c_tsw"]
    lo, hi = model.bounds(gh)
    table13 = {"c_asw": (0.1, 0.9), "c_cnv_ss": (1, 100), "c_cnd_cnv": (1, 300), "c_a": (0.2, 0.7),
               "c_bd": (4, 26), "c_bn": (4, 26), "c_loss": (0.1, 1), "c_tsw": (0.1, 1)}
    for name, (a, b) in table13.items():
        j = model.index(name)
        assert (lo[j], hi[j]) == (a, b)


@pytest.mark.parametrize("which", ["almeria", "prototype", "prototype_vc"])
def test_population_evaluation_equals_one_candidate_at_a_time(which, request):
    model, x, gh = request.getfixturevalue(which)
    theta = random_population(model, gh, 7)
    one = model.one_step(theta, x, gh, 60.0)
    free = model.free_run(theta, x, gh, 60.0)
    assert one.shape == free.shape == (7, len(x["t_in"]))
    for i in range(7):
        np.testing.assert_allclose(one[i], model.one_step(theta[i : i + 1], x, gh, 60.0)[0], rtol=1e-12)
        np.testing.assert_allclose(free[i], model.free_run(theta[i : i + 1], x, gh, 60.0)[0], rtol=1e-12)


def test_frozen_step_matches_a_fine_euler_integration_of_the_frozen_balance(almeria):
    model, x, gh = almeria
    model = replace(model, integration=FROZEN)
    theta = random_population(model, gh, 3, seed=1)
    p = model.columns(theta)
    c = model.capacity(gh)
    t = 700  # midday: sun, vents open
    state = np.full((3, 1), 20.0)
    exact = model.step(p, x, state, t, c, 60.0)
    # Explicit Euler with 60000 sub-steps of 1 ms: converged reference for the frozen step.
    g = sum(term.coefficients(p, x, state, t)[0] for term in model.terms)
    s = sum(term.coefficients(p, x, state, t)[1] for term in model.terms)
    ref = state.copy()
    for _ in range(60000):
        ref = ref + (g - s * ref) * 0.001 / c
    np.testing.assert_allclose(exact, ref, atol=1e-4)


def _rk4_between_samples(model, p, x, state, t, c, dt, n=100):
    """The balance with the drivers linear between samples t and t + 1 (arrays of steps) and
    every coefficient following the state, by RK4 at dt/n: what one step should reach."""
    def rate(f, temp):
        xi = {k: v[t] + f * (v[t + 1] - v[t]) for k, v in x.items()
              if np.ndim(v) == 1 and len(v) == len(x["t_in"])}
        return sum(term.flux(p, xi, temp, slice(None)) for term in model.terms) / c
    h = dt / n
    for i in range(n):
        f = i / n
        k1 = rate(f, state)
        k2 = rate(f + 0.5 / n, state + 0.5 * h * k1)
        k3 = rate(f + 0.5 / n, state + 0.5 * h * k2)
        k4 = rate(f + 1.0 / n, state + h * k3)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return state


@pytest.mark.parametrize("which", ["almeria", "prototype", "prototype_vc"])
def test_step_follows_the_balance_with_drivers_moving_within_the_step(which, request):
    """The default step (first-order hold, re-linearised, gateway/model/step.py) against a fine
    RK4 of the balance whose drivers move linearly from one sample to the next and whose h_i,
    VPD and buoyancy follow the state, from the measured state over a whole day at the default
    parameters: several times closer than the frozen step, whose error is a lag of the drivers."""
    model, x, gh = request.getfixturevalue(which)
    p = model.columns(model.defaults(gh)[None, :])
    c = model.capacity(gh)
    t = np.arange(0, 1439)
    state = x["t_in"][None, t]
    ref = _rk4_between_samples(model, p, x, state, t, c, 60.0)
    new = model.step(p, x, state, t, c, 60.0)
    old = replace(model, integration=FROZEN).step(p, x, state, t, c, 60.0)
    rms_new, rms_old = (float(np.sqrt(np.mean((e - ref) ** 2))) for e in (new, old))
    assert rms_new < 0.2 * rms_old, (rms_new, rms_old)


@pytest.mark.parametrize("which", ["almeria", "prototype_vc"])
@pytest.mark.parametrize("a", [0, 700])  # midnight and midday rows
def test_a_reset_stepper_steps_as_a_new_one_bit_for_bit(which, a, request):
    """The online cost reuses one stepper per search, its parameter columns rewritten in place
    and ``reset`` between populations (gateway/estimate/online.py): the same bits as a new one."""
    model, x, gh = request.getfixturevalue(which)
    x = model.prepare({k: np.asarray(v)[a : a + 4] for k, v in x.items()})
    rows = np.ascontiguousarray(random_population(model, gh, 5).T)
    p = {n: rows[j, :, None] for j, n in enumerate(model.names)}
    reused = model.stepper(p, x, model.capacity(gh), 60.0)
    for seed in (1, 2):
        reused(np.full((5, 1), 20.0), 0)  # a block held from the columns before the rewrite
        rows[:] = random_population(model, gh, 5, seed).T
        reused.reset()
        fresh = model.stepper(p, x, model.capacity(gh), 60.0)
        mine = new = np.full((5, 1), float(x["t_in"][0]))
        for s in range(3):
            mine, new = reused(mine, s), fresh(new, s)
            assert np.array_equal(mine, new), (seed, s)


@pytest.mark.parametrize("which", ["almeria", "prototype_vc"])
def test_a_row_at_a_time_steps_as_all_rows_at_once_bit_for_bit(which, request):
    """``Stepper`` steps one row (an int: ``_step_row``, the online cost's and free runs' path)
    with the same operations as a slice of rows (``__call__``'s general path), over more rows
    than a block (``Stepper.BLOCK``), so a change to one path shows here as a change to both."""
    model, x, gh = request.getfixturevalue(which)
    n = 70
    x = model.prepare({k: np.asarray(v)[650 : 650 + n] for k, v in x.items()})
    rows = np.ascontiguousarray(random_population(model, gh, 5).T)
    p = {name: rows[j, :, None] for j, name in enumerate(model.names)}
    state = x["t_in"][None, :] + np.random.default_rng(3).normal(0.0, 1.0, (5, n))
    at_once = model.stepper(p, x, model.capacity(gh), 60.0)(state, slice(0, n))
    step = model.stepper(p, x, model.capacity(gh), 60.0)
    by_row = np.concatenate([step(state[:, s : s + 1], s) for s in range(n)], axis=1)
    assert np.all(np.isfinite(at_once)) and np.array_equal(by_row, at_once)


def test_one_step_at_the_measured_state_is_what_free_run_does_for_one_step(almeria):
    model, x, gh = almeria
    theta = model.defaults(gh)[None, :]
    one = model.one_step(theta, x, gh, 60.0)
    free = model.free_run(theta, x, gh, 60.0, start=500, stop=502)
    assert one[0, 501] == pytest.approx(free[0, 1])


def test_forecast_is_a_free_run_vectorised_over_start_times(almeria):
    model, x, gh = almeria
    theta = model.defaults(gh)
    starts = np.array([10, 400, 900])
    fc = model.forecast(np.repeat(theta[None, :], 3, axis=0), x, gh, 60.0, starts, horizon=30)
    for k, s0 in enumerate(starts):
        run = model.free_run(theta[None, :], x, gh, 60.0, start=s0, stop=s0 + 31)
        assert fc[k] == pytest.approx(run[0, -1])


def test_free_run_restarts_from_the_measurement_after_a_gap(prototype):
    model, x, gh = prototype
    x = dict(x)
    x["t_out"] = x["t_out"].copy()
    x["t_out"][100:110] = np.nan
    run = model.free_run(model.defaults(gh)[None, :], x, gh, 60.0)[0]
    assert np.isnan(run[101:111]).all()
    # First value after the gap: one step from the measured state at 110.
    one = model.one_step(model.defaults(gh)[None, :], x, gh, 60.0)[0]
    assert run[111] == pytest.approx(one[111])
    assert np.isfinite(run[111:]).all()


def test_fluxes_balance_the_temperature_change(almeria):
    model, x, gh = almeria
    theta = model.defaults(gh)
    run = model.free_run(theta[None, :], x, gh, 60.0)[0]
    q = model.fluxes(theta, x, run)
    assert set(q) == {"q_sol", "q_cnv_ss", "q_cnd_cnv", "q_trp", "q_vent"}
    total = sum(q.values())
    # C dT/dt = sum Q: compare over a calm night hour where the coefficients barely change.
    dTdt = np.gradient(run) / 60.0
    night = slice(60, 120)
    np.testing.assert_allclose(model.capacity(gh) * dTdt[night], total[night], rtol=0.05, atol=0.5)


@pytest.mark.parametrize("which", ["almeria", "prototype"])
def test_fluxes_at_one_minute_are_the_series_fluxes_at_that_minute(which, request):
    """``fluxes_at`` (what the live gateway publishes and a sensor reads) is ``fluxes`` on one
    row; a missing driver or a non-finite flux gives {} rather than a partial or NaN set."""
    model, x, gh = request.getfixturevalue(which)
    theta = model.defaults(gh)
    t = 700
    t_in = x["t_in"]
    series = model.fluxes(theta, x, t_in)
    row = {k: float(v[t]) for k, v in x.items() if np.ndim(v) == 1 and len(v) == len(t_in)}
    one = model.fluxes_at(theta, row, float(t_in[t]))
    assert set(one) == set(series) and one
    for name, v in one.items():
        assert v == pytest.approx(float(series[name][t]), rel=1e-12, abs=1e-12)
    assert model.fluxes_at(theta, row, float("nan")) == {}
    assert model.fluxes_at(theta, {k: v for k, v in row.items() if k != "t_out"}, 20.0) == {}


def test_vent_areas_follow_iii33_and_iii34(almeria_gh):
    v = almeria_gh.vents
    assert side_vent_area(v, np.array(50.0)) == pytest.approx(2 * 32.75 * 1.90 * 0.5)
    full = roof_vent_area(v, np.array(100.0))
    assert full == pytest.approx(5 * 2 * 8.36 * 0.73 * np.sin(np.radians(v.roof_max_angle / 2)))
    assert roof_vent_area(v, np.array(0.0)) == 0.0


def test_free_run_is_stable_for_15_days_at_every_corner_of_the_box(weather_minutes, almeria_gh):
    """All 2^10 corners of the table-13 box at once: 15 days of free run stay finite, inside the
    equilibrium envelope the exact step guarantees, and inside [-50, 100] °C. (An explicit
    Euler step at dt = 60 s diverges here: C_ter / C_cnd_cnv,max ≈ 14 s.)"""
    model = build_model("almeria", almeria_gh)
    series = almeria_like_series(weather_minutes, days=15)
    x = prepare_drivers(series, almeria_gh)
    lo, hi = model.bounds(almeria_gh)
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    # the calibrated (table 8) parameters as a 1025th row of the same run: one pass of the
    # 21600 steps, not two (a row's run is the single-row run: checked by
    # test_population_evaluation_equals_one_candidate_at_a_time; here bit for bit, 2026-11-29)
    both = model.free_run(np.vstack([corners, model.defaults(almeria_gh)[None, :]]), x,
                          almeria_gh, 60.0)
    run, typical = both[:1024], both[1024]
    assert run.shape == (1024, 15 * 1440)
    assert np.isfinite(run).all()
    assert run.min() > -50.0 and run.max() < 100.0
    # Calibrated (table 8) parameters stay near the weather that drives them.
    assert series["t_out"].min() - 5 < typical.min() and typical.max() < series["t_out"].max() + 25
    # The explicit Euler step is unstable at the stiff corner: the reason for the exact step.
    assert model.capacity(almeria_gh) / hi[model.index("c_cnd_cnv")] < 60.0


@pytest.mark.parametrize("which", ["almeria", "prototype", "prototype_vc", "prototype_hc"])
def test_each_terms_slope_is_minus_the_derivative_of_its_flux(which, request):
    """FluxTerm.linearised: k = -dQ/dT_in (central differences), for a population over a day."""
    model, x, gh = request.getfixturevalue(which)
    p = model.columns(random_population(model, gh, 5, seed=4))
    t = slice(0, 1440)
    state = x["t_in"][None, t] + np.linspace(-4.0, 4.0, 5)[:, None]
    h = 1e-4
    for term in model.terms:
        g, s, k = (np.broadcast_to(v, state.shape) for v in term.linearised(p, x, state, t))
        num = -(term.flux(p, x, state + h, t) - term.flux(p, x, state - h, t)) / (2 * h)
        num = np.broadcast_to(num, state.shape)
        smooth = np.abs(state - x["t_out"][None, t]) > 0.05  # |ΔT|^0.33 and |ΔT| kink at 0
        np.testing.assert_allclose(k[smooth], num[smooth], rtol=1e-5, atol=1e-9, err_msg=term.name)
        g0, s0 = term.coefficients(p, x, state, t)
        np.testing.assert_allclose(g, np.broadcast_to(g0, state.shape), rtol=1e-12)
        np.testing.assert_allclose(s, np.broadcast_to(s0, state.shape), rtol=1e-12)


@pytest.mark.parametrize("which", ["almeria", "prototype", "prototype_vc"])
def test_a_model_pickles_and_runs_the_same_after(which, request):
    """The studies and the suite hand models (and replay results holding them) to process
    pools: the terms' activity conditions must not be lambdas."""
    import pickle

    model, x, gh = request.getfixturevalue(which)
    theta = random_population(model, gh, 3)
    back = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(back.free_run(theta, x, gh, 60.0), model.free_run(theta, x, gh, 60.0))

"""The calibration cost: the fast one-step path equals the model's own evaluation."""

import numpy as np
import pytest
from conftest import almeria_like_series

from gateway.estimate.objective import Objective
from gateway.model import build_model
from gateway.model.drivers import prepare_drivers


@pytest.mark.parametrize("which", ["prototype", "almeria"])
def test_fast_one_step_cost_equals_model_one_step(which, weather_minutes, request):
    gh = request.getfixturevalue(f"{which}_gh")
    model = build_model(which, gh)
    series = almeria_like_series(weather_minutes, days=1)
    series.columns["t_in"][100:130] = np.nan  # a gap in the measurement
    x = prepare_drivers(series, gh)
    lo, hi = model.bounds(gh)
    theta = lo + np.random.default_rng(2).random((9, len(lo))) * (hi - lo)
    free = np.array([j for j, n in enumerate(model.names) if n != "c_tsw"])
    obj = Objective(model, x, gh, 60.0, free, model.defaults(gh), [(0, 700), (800, 1440)])
    assert obj._fast is not None
    fast = obj(theta[:, free])
    ref = []
    for i in range(9):
        full = obj.full(theta[i : i + 1, free])
        errs = []
        for a, b in [(0, 700), (800, 1440)]:
            part = {k: v[a:b] for k, v in x.items()}
            pred = model.one_step(full, part, gh, 60.0)[0]
            errs.append((pred - part["t_in"])[1:])
        e = np.concatenate(errs)
        ref.append(np.nanmean(e**2))
    np.testing.assert_allclose(fast, ref, rtol=1e-10)


@pytest.mark.parametrize("which", ["prototype", "almeria"])
def test_terms_flagged_linear_are_linear_in_their_parameters(which, weather_minutes, request):
    gh = request.getfixturevalue(f"{which}_gh")
    model = build_model(which, gh)
    x = prepare_drivers(almeria_like_series(weather_minutes, days=1), gh)
    rng = np.random.default_rng(5)
    lo, hi = model.bounds(gh)
    theta = lo + rng.random((2, len(lo))) * (hi - lo)
    state = x["t_in"][None, :]
    for term in model.terms:
        if not term.linear_in_parameters:
            continue
        own = [model.index(p.name) for p in term.parameters]
        other = theta[0].copy()  # the two points differ only in the term's own parameters
        other[own] = theta[1, own]
        theta = np.array([theta[0], other])
        mix = theta[0].copy()
        mix[own] = 0.3 * theta[0, own] + 0.7 * theta[1, own]
        coef = [term.coefficients(model.columns(v[None, :]), x, state, slice(None)) for v in
                (theta[0], theta[1], mix)]
        for k in range(2):
            a, b, m = (np.asarray(c[k], dtype=float) for c in coef)
            np.testing.assert_allclose(m, 0.3 * a + 0.7 * b, rtol=1e-9, atol=1e-12)

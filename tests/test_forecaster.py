"""The live forecaster (gateway/service/forecaster.py) gives replay's forecasts step by step and
resumes exactly from its snapshot."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_online import ALMERIA, FAST, GH, model_data

from gateway.estimate import correction
from gateway.estimate.horizon import INSIDE_READINGS
from gateway.estimate.online import online_settings
from gateway.estimate.replay import replay, score_forecasts, steps_of
from gateway.service.forecaster import KINDS, LiveForecaster

HORIZONS = (15, 60)


class QuickCorrector(correction.Corrector):
    """The correction applied after an hour of matured errors instead of a day, so that a
    series shorter than a day exercises it."""

    def __init__(self, horizons, dt, *args) -> None:
        super().__init__(horizons, dt, correction.MEMORY_S, correction.RIDGE, 3600.0)


@pytest.fixture(scope="module")
def result():
    series = model_data(ALMERIA, GH, hours=8, seed=3)
    return replay(ALMERIA, series, GH, settings=online_settings(ALMERIA, GH, FAST), horizons=HORIZONS)


def live_forecasts(res, kind: str, restart: bool = False) -> tuple[dict[int, np.ndarray], int]:
    """The live forecaster fed ``res``'s rows and parameters step by step, the weather later
    measured as its outlook: {h: forecast made at t} and the first start not run (with
    ``restart``, through a JSON round trip of its state half-way)."""
    x, theta, n = res.x, res.theta, len(res.measured)
    live = LiveForecaster(ALMERIA, GH, res.dt, HORIZONS, kind)
    got = {h: np.full(n, np.nan) for h in HORIZONS}
    stop = n - max(HORIZONS) - 1
    for t in range(stop):
        if restart and t == stop // 2:
            snap = json.loads(json.dumps(live.snapshot()))
            live = LiveForecaster(ALMERIA, GH, res.dt, HORIZONS, kind)
            live.restore(snap)
        live.update({k: float(v[t]) for k, v in x.items()}, theta[t], res.time[t])
        if np.isfinite(res.measured[t]):
            # the weather as later measured, the inside readings as at t (a model-skill
            # forecast's drivers, gateway/estimate/horizon.py INSIDE_READINGS)
            block = {k: np.full(max(HORIZONS) + 1, v[t]) if k in INSIDE_READINGS
                     else v[t: t + max(HORIZONS) + 1] for k, v in x.items()}
            for h, v in live.forecasts(theta[t], block, HORIZONS).items():
                got[h][t] = v
    return got, stop


@pytest.mark.parametrize("kind", KINDS)
def test_step_by_step_is_the_replay_forecast(result, kind):
    """Fed the replay's rows and parameters, with the weather later measured as its outlook, the
    live forecaster reproduces replay's row of the same name (through a JSON round trip of its
    state half-way)."""
    got, stop = live_forecasts(result, kind, restart=True)
    for h in HORIZONS:
        f = result.horizons[h]
        starts = f["target"] - h
        keep = starts < stop
        ok = keep & np.isfinite(f[kind])
        assert ok.sum() > 300
        np.testing.assert_allclose(got[h][starts[ok]], f[kind][ok], rtol=0, atol=1e-9)


def test_the_applied_correction_is_the_replays(result, monkeypatch):
    """With the correction applied from an hour on (the 8-hour series has no day to learn
    from), the live forecaster's ``corrected``, its φ with the change of the weather it is given
    (the block's rows), is replay's row again, and differs from ``combined``."""
    from dataclasses import replace as copy_with

    monkeypatch.setattr(correction, "Corrector", QuickCorrector)
    res = copy_with(result, horizons={})
    score_forecasts(res, steps_of(HORIZONS, res.dt))
    got, stop = live_forecasts(res, "corrected")
    for h in HORIZONS:
        f = res.horizons[h]
        starts = f["target"] - h
        ok = (starts < stop) & np.isfinite(f["corrected"])
        assert np.mean(np.abs(f["corrected"][ok] - f["combined"][ok]) > 1e-3) > 0.5
        np.testing.assert_allclose(got[h][starts[ok]], f["corrected"][ok], rtol=0, atol=1e-9)


def test_unknown_kind_and_a_foreign_state():
    with pytest.raises(ValueError, match="unknown forecast 'best'"):
        LiveForecaster(ALMERIA, GH, 60.0, HORIZONS, "best")
    a = LiveForecaster(ALMERIA, GH, 60.0, HORIZONS, "adaptive_kf")
    b = LiveForecaster(ALMERIA, GH, 60.0, HORIZONS, "combined")
    b.restore(a.snapshot())  # another kind's state: start afresh
    assert b.kf is not None and b.kf.estimate() is None and b.arx is not None


def test_a_combined_state_goes_on_as_corrected(result):
    """A gateway that published ``combined`` and restarts with ``corrected`` (the default since
    the correction) keeps the filter, the ARX and the combiner's errors; the correction starts
    afresh."""
    x, theta = result.x, result.theta
    a = LiveForecaster(ALMERIA, GH, result.dt, HORIZONS, "combined")
    for t in range(200):
        a.update({k: float(v[t]) for k, v in x.items()}, theta[t], result.time[t])
        block = {k: v[t: t + max(HORIZONS) + 1] for k, v in x.items()}
        a.forecasts(theta[t], block, HORIZONS)
    b = LiveForecaster(ALMERIA, GH, result.dt, HORIZONS, "corrected")
    b.restore(json.loads(json.dumps(a.snapshot())))
    assert b.arx is not None and a.arx is not None and b.arx.updates == a.arx.updates > 100
    assert b.comb is not None and b.comb.snapshot() == a.comb.snapshot()
    assert b.kf is not None and b.kf.estimate() == a.kf.estimate()
    assert b.corr is not None and not any(b.corr.pending.values())

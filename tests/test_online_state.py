"""Online estimator state: a snapshot through JSON restores the exact run (the live gateway saves
it every minute); a window restart after a gap keeps the parameters."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gateway.estimate.online import OnlineEstimator, online_settings
from tests.test_online import ALMERIA, FAST, GH, model_data, samples


def test_snapshot_through_json_resumes_the_exact_run() -> None:
    data = list(samples(model_data(ALMERIA, GH, hours=3.0, seed=4)))
    settings = online_settings(ALMERIA, GH, FAST)
    whole = OnlineEstimator(ALMERIA, GH, settings=settings, seed=3)
    ref = [whole.update(s) for s in data]
    first = OnlineEstimator(ALMERIA, GH, settings=settings, seed=3)
    for s in data[:97]:
        first.update(s)
    snap = json.loads(json.dumps(first.snapshot()))
    second = OnlineEstimator(ALMERIA, GH, settings=settings, seed=99)  # other seed: restored
    second.restore(snap)
    rest = [second.update(s) for s in data[97:]]
    for a, b in zip(ref[97:], rest, strict=True):
        assert a.t_in == b.t_in
        np.testing.assert_array_equal(a.theta, b.theta)
    assert second.counters == whole.counters


def test_restore_refuses_another_model_and_gap_keeps_parameters() -> None:
    from gateway.model import build_model

    est = OnlineEstimator(ALMERIA, GH, settings=online_settings(ALMERIA, GH, FAST))
    data = list(samples(model_data(ALMERIA, GH, hours=1.0)))
    for s in data[:30]:
        est.update(s)
    theta = est.theta.copy()
    est.restart_window()
    pred = est.update(data[30])
    np.testing.assert_array_equal(pred.theta, theta)  # nothing estimated on an empty window
    assert pred.estimated == ()
    proto = OnlineEstimator(build_model("prototype", GH), GH)
    with pytest.raises(ValueError, match="almeria"):
        proto.restore(est.snapshot())


def test_the_cloud_tracker_resumes_exactly() -> None:
    """The sky's cloudiness is part of the saved state: a tracker restored from a snapshot gives
    bit for bit what the uninterrupted one gives."""
    from gateway.model.sky import CloudTracker

    t0 = np.datetime64("2009-10-20T06:00:00", "s")
    times = t0 + np.arange(0, 3 * 1440) * np.timedelta64(60, "s")
    hours = (np.arange(len(times)) / 60.0) % 24
    i_glob = np.clip(500 * np.sin((hours - 6) / 12 * np.pi), 0, None) * (0.5 + 0.4 * np.sin(hours))
    a = CloudTracker((52.03, 4.53), 60.0)
    first = [a.update(t, g) for t, g in zip(times[:2000], i_glob[:2000], strict=True)]
    b = CloudTracker((52.03, 4.53), 60.0)
    b.restore(json.loads(json.dumps(a.state())))
    rest_a = [a.update(t, g) for t, g in zip(times[2000:], i_glob[2000:], strict=True)]
    rest_b = [b.update(t, g) for t, g in zip(times[2000:], i_glob[2000:], strict=True)]
    assert rest_a == rest_b and len(set(first)) > 10

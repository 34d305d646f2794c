"""Forecast combination by recent skill: weights, causality, never much worse than its parts."""

from __future__ import annotations

import numpy as np

from gateway.estimate.combination import combine, trailing_mean, weights

H = 6
WINDOW = 288


def _two(seed: int = 0, n: int = 3000, sd=(0.1, 0.2)):
    """A signal and two unbiased forecasts of it h steps ahead with independent errors."""
    rng = np.random.default_rng(seed)
    measured = np.cumsum(rng.normal(0, 0.05, n))
    target = np.full(n, np.nan)
    target[: n - H] = measured[H:]
    return measured, {"a": target + rng.normal(0, sd[0], n), "b": target + rng.normal(0, sd[1], n)}


def test_trailing_mean_skips_missing_values():
    v = np.array([1.0, np.nan, 3.0, 5.0])
    np.testing.assert_allclose(trailing_mean(v, 2), [1.0, 1.0, 3.0, 4.0])
    assert np.isnan(trailing_mean(np.array([np.nan, 2.0]), 1)[0])


def test_weights_are_the_inverse_mean_square_errors():
    measured, f = _two()
    w = weights(f, measured, H, WINDOW)
    late = slice(1000, -H)
    # errors 0.1 and 0.2 K: weights 1/0.01 : 1/0.04 = 0.8 : 0.2
    assert abs(np.mean(w["a"][late]) - 0.8) < 0.03
    np.testing.assert_allclose(w["a"] + w["b"], 1.0)
    assert np.all(w["a"][:H] == 1.0) and np.all(w["b"][:H] == 0.0)  # nothing matured yet
    assert w["a"][H] < 1.0  # at t = h the forecast made at 0 has met its target


def test_combination_beats_both_parts_when_they_err_independently():
    measured, f = _two(seed=1, sd=(0.15, 0.15))
    c = combine(f, measured, H, WINDOW)
    target = measured[1000 + H:]
    mae = {k: np.mean(np.abs(v[1000:-H] - target)) for k, v in {**f, "c": c}.items()}
    assert mae["c"] < 0.8 * min(mae["a"], mae["b"])  # independent errors: 1/√2 in theory


def test_weights_at_t_read_no_target_after_t():
    measured, f = _two(seed=2)
    a = weights(f, measured, H, WINDOW)
    t = 1500
    later = measured.copy()
    later[t + 1:] += 10.0  # another future
    b = weights(f, later, H, WINDOW)
    np.testing.assert_array_equal(a["a"][: t + 1], b["a"][: t + 1])
    assert not np.allclose(a["a"][t + 10], b["a"][t + 10])


def test_the_live_combiner_step_by_step_gives_the_series_weights_and_resumes():
    import json

    from gateway.estimate.combination import LiveCombiner

    measured, f = _two(seed=3, n=900)
    measured[100:104] = np.nan
    f["b"][200:210] = np.nan  # a forecast that could not be made
    window = 96
    whole = weights(f, measured, H, window)
    live = LiveCombiner(["a", "b"], [H], window)
    for t in range(len(measured)):
        if t == 450:  # a restarted gateway
            snap = json.loads(json.dumps(live.snapshot()))
            live = LiveCombiner(["a", "b"], [H], window)
            live.restore(snap)
        live.step(measured[t], {H: {"a": f["a"][t], "b": f["b"][t]}})
        w = live.weights(H)
        assert abs(w["a"] - whole["a"][t]) < 1e-12, t


def test_a_diverging_part_is_left_out_and_scored_at_the_range_edge() -> None:
    """A linear baseline that diverges (as the RLS ARX did on 1-minute data that barely excite
    it) must not drag the combination with it: a tiny weight times 1e50 is still 1e50."""
    from gateway.estimate.combination import LiveCombiner, combine, mix

    n, h = 400, 3
    measured = 20.0 + np.sin(np.arange(n) / 20.0)
    good = np.roll(measured, -h) + 0.1
    bad = good.copy()
    bad[200:] = 1e50 * np.arange(1, n - 199)  # explodes half-way
    mixed = combine({"good": good, "bad": bad}, measured, h, 100)
    assert np.all(np.abs(mixed[200:n - h] - good[200:n - h]) < 1e-9)
    live = LiveCombiner(["good", "bad"], [h], 100)
    out = []
    for t in range(n):
        live.observe(measured[t])
        w = live.weights(h)
        out.append(mix({"good": good[t], "bad": bad[t]}, w))
        live.add({h: {"good": good[t], "bad": bad[t]}})
    np.testing.assert_allclose(out[210:n - h], good[210:n - h], atol=1e-9)
    assert max(live.errors[h]["bad"]) <= (80.0 - 19.0) ** 2  # scored at the range's edge


def test_a_record_shorter_than_the_horizon_has_nothing_matured():
    """16 samples and h = 30 (a short kit CSV replayed): no target in the record, so every start
    keeps the first forecast's weight, and the combination is that forecast (it raised before)."""
    measured, f = _two(n=16)
    w = weights(f, measured, 30, WINDOW)
    assert np.all(w["a"] == 1.0) and np.all(w["b"] == 0.0)
    np.testing.assert_array_equal(combine(f, measured, 30, WINDOW), f["a"])

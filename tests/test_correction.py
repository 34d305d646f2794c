"""Online error correction of a forecast (gateway/estimate/correction.py): it learns a bias,
reads no outcome later than its start, and the live step-by-step form resumes exactly."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gateway.estimate import correction
from gateway.estimate.correction import (
    FEATURES,
    MAX_CORRECTION_K,
    Corrector,
    correct_series,
    hour_of_day,
)

H = 6
DT = 300.0


def _series(seed: int = 0, n: int = 2000, bias: float = 0.8):
    """A temperature, its drivers and times, and a forecast of it H steps ahead off by ``bias``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    measured = 18.0 + 3.0 * np.sin(2 * np.pi * t / 288) + np.cumsum(rng.normal(0, 0.02, n))
    target = np.full(n, np.nan)
    target[: n - H] = measured[H:]
    x = {"i_glob": np.clip(600 * np.sin(2 * np.pi * t / 288), 0, None),
         "t_out": measured - 6.0 + rng.normal(0, 0.5, n)}
    time = np.datetime64("2020-01-01T00:00", "s") + t * np.timedelta64(int(DT), "s")
    forecast = target - bias + rng.normal(0, 0.1, n)
    return measured, x, time, forecast


def _mae_late(measured, f):
    return float(np.mean(np.abs(f[1000:-H] - measured[1000 + H:])))


def test_it_learns_a_constant_bias():
    measured, x, time, forecast = _series()
    corrected = correct_series({H: forecast}, measured, x, time, DT)[H]
    before, after = _mae_late(measured, forecast), _mae_late(measured, corrected)
    assert before > 0.75 and after < 0.15, (before, after)


def test_an_unbiased_forecast_is_left_nearly_alone():
    measured, x, time, forecast = _series(seed=1, bias=0.0)
    corrected = correct_series({H: forecast}, measured, x, time, DT)[H]
    before, after = _mae_late(measured, forecast), _mae_late(measured, corrected)
    assert after < 1.05 * before, (before, after)


def test_the_correction_at_t_reads_no_outcome_after_t():
    """Another future after t changes nothing up to t: a correction at t uses the targets of
    the starts up to t − H only (measured at t at the latest)."""
    measured, x, time, forecast = _series(seed=2)
    a = correct_series({H: forecast}, measured, x, time, DT)[H]
    t = 1200
    later = measured.copy()
    later[t + 1:] += 5.0
    b = correct_series({H: forecast}, later, x, time, DT)[H]
    np.testing.assert_array_equal(a[: t + 1], b[: t + 1])
    assert not np.allclose(a[t + H + 1: t + 50], b[t + H + 1: t + 50])


def test_the_outcome_of_a_start_is_first_used_h_steps_later():
    """A single error at start s moves the correction from s + H on, not before."""
    n = 200
    measured = np.full(n, 20.0)
    forecast = np.full(n, 20.0)
    x = {"i_glob": np.zeros(n), "t_out": np.full(n, 15.0)}
    time = np.datetime64("2020-01-01T00:00", "s") + np.arange(n) * np.timedelta64(300, "s")
    s = 100
    forecast[s] = 19.0  # the start s errs by +1 K (its target is 20 at s + H)
    out = correct_series({H: forecast}, measured, x, time, DT, warmup_s=0.0)[H]
    assert np.all(out[:s] == forecast[:s])
    assert np.all(out[s + 1: s + H] == forecast[s + 1: s + H])
    assert out[s + H] > 20.0


def test_nothing_is_corrected_before_a_day_of_matured_starts():
    measured, x, time, forecast = _series(seed=7)
    out = correct_series({H: forecast}, measured, x, time, DT)[H]
    day = int(86400 / DT)
    first = day + H - 1  # at t the starts 0 … t − H have matured: a day of them at t = day + H − 1
    np.testing.assert_array_equal(out[:first], forecast[:first])
    assert np.all(out[first:] != forecast[first:])


def test_the_correction_is_bounded_and_a_missing_forecast_stays_missing():
    measured, x, time, forecast = _series(seed=3, bias=50.0)
    forecast[500:510] = np.nan
    out = correct_series({H: forecast}, measured, x, time, DT)[H]
    assert np.all(np.isnan(out[500:510]))
    ok = np.isfinite(out)
    assert np.all(np.abs(out[ok] - forecast[ok]) <= MAX_CORRECTION_K + 1e-12)
    assert np.mean(np.abs(out[ok] - forecast[ok]) > MAX_CORRECTION_K - 1e-9) > 0.5


def test_the_stacked_forecast_is_weighted_in():
    """Given a second forecast that is better, the correction moves toward it."""
    measured, x, time, forecast = _series(seed=5, bias=0.0)
    rng = np.random.default_rng(6)
    target = np.concatenate([measured[H:], np.full(H, np.nan)])
    poor = target + rng.normal(0, 0.4, len(target))
    good = target + rng.normal(0, 0.1, len(target))
    out = correct_series({H: poor}, measured, x, time, DT, {H: good})[H]
    assert _mae_late(measured, out) < 0.6 * _mae_late(measured, poor)


def test_a_controlled_house_going_back_to_its_day_mean_is_learnt(monkeypatch):
    """A forecast that misses how far the house goes back toward its usual temperature (its
    error a share of the reading's departure from the last day's mean): the level and departure
    features learn it; the day mean is that of the readings observed so far."""
    rng = np.random.default_rng(8)
    n = 2000
    excursion = np.zeros(n)  # a regulated house: kicks away from 21 °C that decay
    for t in range(1, n):
        kick = rng.choice([-6.0, 6.0]) if t % 37 == 0 else 0.0
        excursion[t] = 0.9 * excursion[t - 1] + kick + rng.normal(0, 0.02)
    measured = 21.0 + excursion
    x = {"i_glob": np.zeros(n), "t_out": np.full(n, 10.0)}
    time = np.datetime64("2020-01-01T00:00", "s") + np.arange(n) * np.timedelta64(300, "s")
    forecast = measured.copy()  # persistence: it misses the way back
    forecast[: n - H] = measured[: n - H]
    forecast[n - H:] = np.nan
    corrected = correct_series({H: forecast}, measured, x, time, DT)[H]
    mask = np.array([0.0 if n.startswith("t_in") else 1.0 for n in FEATURES])
    full = correction.features
    monkeypatch.setattr(correction, "features", lambda *a: full(*a) * mask)
    without = correct_series({H: forecast}, measured, x, time, DT)[H]
    starts = np.arange(1000, n - H)
    calm = (starts % 37) < 37 - H  # no kick within the horizon (a kick is not foreseeable)
    err = {k: np.mean(np.abs(f[starts][calm] - measured[starts + H][calm]))
           for k, f in (("before", forecast), ("without", without), ("after", corrected))}
    assert err["after"] < 0.6 * err["before"] and err["after"] < 0.8 * err["without"], err
    live = Corrector([H], DT)
    for v in measured[:400]:
        live.observe(float(v))
    assert live.day_mean == pytest.approx(np.mean(measured[400 - 288:400]))


def test_an_older_snapshot_starts_afresh():
    """A state saved with another φ (before the T_in features: 8 columns) is not mixed in."""
    k = len(FEATURES) - 2
    old = {"r_mat": {str(H): np.eye(k).tolist()}, "r_vec": {str(H): [0.0] * k},
           "last": {str(H): 0.1}, "learnt": {str(H): 500}, "pending": {str(H): [[0.0] * (k + 1)]}}
    live = Corrector([H], DT)
    live.restore(old)
    assert live.learnt[H] == 0 and len(live.pending[H]) == 0
    live.observe(20.0)
    assert live.correct(H, 20.5, 20.0, {"i_glob": 0.0, "t_out": 10.0, "hour": 3.0}) == 20.5


def test_hour_of_day():
    t = np.array(["2020-03-01T00:00", "2020-03-01T13:30"], dtype="datetime64[s]")
    np.testing.assert_allclose(hour_of_day(t), [0.0, 13.5])


def test_live_steps_resume_from_a_snapshot():
    measured, x, time, forecast = _series(seed=4, n=800)
    whole = correct_series({H: forecast}, measured, x, time, DT)[H]
    hours = hour_of_day(time)
    live = Corrector([H], DT)
    got = np.full(len(measured), np.nan)
    for t in range(len(measured)):
        if t == 400:  # a restarted gateway
            snap = json.loads(json.dumps(live.snapshot()))
            live = Corrector([H], DT)
            live.restore(snap)
        live.observe(float(measured[t]))
        if math.isfinite(forecast[t]):
            row = {"i_glob": float(x["i_glob"][t]), "t_out": float(x["t_out"][t]),
                   "hour": float(hours[t])}
            got[t] = live.correct(H, float(forecast[t]), float(measured[t]), row)
        live.add()
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-12)


def test_a_forecast_that_misses_its_own_weather_change_is_corrected(monkeypatch):
    """A forecast that under-responds to the change of its drivers over its horizon (half the
    warming of a sunny spell that starts within it is missed): the Δ features (``ahead_change``
    of the drivers the forecast reads) learn it; with them held at 0 the rest of φ does not."""
    rng = np.random.default_rng(11)
    n = 2000
    spells = np.repeat(rng.uniform(0.0, 600.0, n // 12 + 1), 12)[:n]  # an hour of sun or cloud
    x = {"i_glob": spells, "wind": np.full(n, 2.0), "t_out": np.full(n, 12.0)}
    warmed = 4e-3 * np.concatenate([[0.0], spells[:-1]])  # [K]: the house follows the sun
    measured = 18.0 + warmed + rng.normal(0.0, 0.05, n)
    time = np.datetime64("2020-01-01T00:00", "s") + np.arange(n) * np.timedelta64(300, "s")
    starts = np.arange(n - H)
    change = correction.ahead_change(x, starts, H)
    forecast = np.full(n, np.nan)  # right but for half the warming its sun brings
    forecast[starts] = 18.0 + warmed[starts + H] - 0.5 * 4e-3 * change["d_i_glob"]
    ahead = {H: {k: np.concatenate([v, np.full(H, np.nan)]) for k, v in change.items()}}
    corrected = correct_series({H: forecast}, measured, x, time, DT, ahead=ahead)[H]
    mask = np.array([0.0 if n.endswith(" ahead") else 1.0 for n in FEATURES])
    full = correction.features
    monkeypatch.setattr(correction, "features", lambda *a: full(*a) * mask)
    without = correct_series({H: forecast}, measured, x, time, DT, ahead=ahead)[H]
    err = {k: _mae_late(measured, f) for k, f in
           (("before", forecast), ("without", without), ("after", corrected))}
    assert err["after"] < 0.5 * err["before"] and err["after"] < 0.6 * err["without"], err


def test_the_weather_change_is_read_from_the_rows_the_forecast_reads():
    """``ahead_change`` of a start is its last driver row (start + h − 1) less its first: the
    same from a series and from a block laid out per start (gateway/estimate/horizon.py)."""
    rng = np.random.default_rng(12)
    n = 50
    x = {c: rng.normal(0.0, 1.0, n) for c in correction.AHEAD}
    starts = np.arange(0, n - H)
    blocks = {c: np.stack([v[s: s + H + 1] for s in starts]).ravel() for c, v in x.items()}
    from_series = correction.ahead_change(x, starts, H)
    from_blocks = correction.ahead_change(blocks, starts * (H + 1), H)
    for c in correction.AHEAD:
        np.testing.assert_array_equal(from_series[f"d_{c}"], from_blocks[f"d_{c}"])
        np.testing.assert_array_equal(from_series[f"d_{c}"], x[c][starts + H - 1] - x[c][starts])
    assert np.all(correction.ahead_change(x, starts, 1)["d_i_glob"] == 0.0)  # one step: no change

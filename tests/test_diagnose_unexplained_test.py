"""Issue 10: ``day_test.day_test`` and ``UNEXPLAINED_TEST``, a flag that does not need a bad
base. Synthetic residuals only: 14 days at 10 min, calibration the first 7."""

from __future__ import annotations

import numpy as np

from gateway.diagnose import day_test as dtest
from gateway.diagnose import residuals as res

DT = 600
DAY = 86400 // DT


def _synth(seed: int, dip: float = 0.0, shift: float = 0.8, sd: float = 0.3,
           wander: float = 0.3) -> tuple[np.ndarray, np.ndarray, int]:
    """AR(1) in time (τ = 1 h, stationary s.d. ``sd``) plus a slow day-to-day random walk
    (``wander`` K per √day / 3), ``shift`` K over the whole held-out part, and a daily dip of
    ``dip`` K 12:00–13:30 UTC in the held-out days only."""
    rng = np.random.default_rng(seed)
    n = 14 * DAY
    t = np.datetime64("2026-06-01T00:00") + np.arange(n) * np.timedelta64(DT, "s")
    phi = np.exp(-DT / 3600)
    e = rng.normal(0.0, sd * np.sqrt(1 - phi**2), n)
    r = np.empty(n)
    r[0] = rng.normal(0.0, sd)
    for i in range(1, n):
        r[i] = phi * r[i - 1] + e[i]
    r += wander * np.repeat(np.cumsum(rng.normal(0.0, 1.0, 14)) / 3, DAY)
    a = 7 * DAY
    r[a:] += shift
    sec = (np.arange(n) * DT) % 86400
    r[a:] -= dip * ((sec[a:] >= 12 * 3600) & (sec[a:] < 13.5 * 3600))
    return t, r, a


def _an(r: np.ndarray) -> dict:
    return {"mean": float(np.mean(r)), "mae": float(np.mean(np.abs(r))), "correlations": {},
            "hour_profile": np.full(24, np.nan), "acf_1h": np.nan, "acf_1d": np.nan,
            "change_points": {}}


def test_scheduled_dip_in_held_out_days_is_flagged_and_named():
    hits = 0
    for seed in range(10):
        t, r, a = _synth(seed, dip=0.5, sd=0.15)
        d = dtest.day_test(t[a:], r[a:], t[:a], r[:a])
        hits += d.p < dtest.UNEXPLAINED_ALPHA
        if d.bins:  # 12:00-13:30 UTC named, the strongest of them a dip there
            assert {24, 25} <= set(d.bins)
            assert 24 <= d.bins[int(np.argmin(d.diff))] <= 26 and min(d.diff) < -0.3
    assert hits >= 9


def test_size_regime_shift_and_wander_not_flagged():
    """AR(1) noise, +0.8 K over the held-out part, day-to-day wander: ≤ 5 (α) of 100 seeds
    flagged, up to sampling scatter (measured 6 of 100 at 5-min steps; here it is asserted
    ≤ 10, binomial 100 × 0.05 + 2.3 s.d.)."""
    flags = 0
    for seed in range(100):
        t, r, a = _synth(seed)
        flags += dtest.day_test(t[a:], r[a:], t[:a], r[:a]).p < dtest.UNEXPLAINED_ALPHA
    assert flags <= 10


def test_switch_flags_on_structure_not_on_base_error(monkeypatch):
    """Big held-out MAE from a regime shift alone: the old rule flags it (ratio > 2), the test
    does not; a scheduled dip is flagged with its hours in the signature."""
    t, r, a = _synth(3, shift=1.5, sd=0.15)
    old, _ = res.unexplained(_an(r[a:]), r[:a], t, a, r[a:])
    monkeypatch.setattr(res, "UNEXPLAINED_TEST", True)
    new, sig = res.unexplained(_an(r[a:]), r[:a], t, a, r[a:])
    assert old and not new and "day-swap p" in sig
    t, r, a = _synth(3, dip=0.6, shift=0.0, sd=0.15)
    flag, sig = res.unexplained(_an(r[a:]), r[:a], t, a, r[a:])
    assert flag and "12:" in sig and "a scheduled action?" in sig


def test_default_off():
    assert res.UNEXPLAINED_TEST is False

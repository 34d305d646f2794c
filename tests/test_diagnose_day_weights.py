"""The day test's matched-filter form (``significance.day_p`` with ``weights``, ``judge.DAY_WEIGHTS``;
rule wd, docs/effects.md "A day test weighted by the candidate's own change"): its size under
the declared day correlation with weights that do not see the errors, its identity with the
plain day test at equal weights, its power on a cut that follows the weights, and the weights
the judge gives it."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import judge as jd
from gateway.diagnose import significance as sig


def _ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    """Stationary AR(1) of unit variance."""
    out = np.empty(n)
    out[0] = rng.normal()
    for i in range(1, n):
        out[i] = phi * out[i - 1] + np.sqrt(1 - phi**2) * rng.normal()
    return out


def _day_null(rng: np.random.Generator, days: int, phi_d: float, share: float = 0.6) -> np.ndarray:
    """Null piece differences, 4 pieces a day: a day effect AR(1) across days carrying
    ``share`` of the variance, plus independent piece noise (as tests/test_diagnose_judge.py)."""
    return (np.sqrt(share) * np.repeat(_ar1(rng, days, phi_d), 4)
            + np.sqrt(1 - share) * rng.normal(size=4 * days))


def _weights(rng: np.random.Generator, days: int, zeros: bool) -> np.ndarray:
    """Weather-like day weights, drawn apart from the errors: log-normal and correlated from
    day to day, or with calm days at exactly 0."""
    u = _ar1(rng, days, 0.6)
    return np.clip(0.4 + 0.5 * u, 0.0, None) if zeros else np.exp(0.8 * u)


@pytest.mark.parametrize("days", [7, 4])
@pytest.mark.parametrize("phi_d", [0.0, 0.3, sig.DAY_RHO])
@pytest.mark.parametrize("zeros", [False, True])
def test_weighted_day_p_holds_its_size(days, phi_d, zeros):
    """Up to the declared day correlation, with weights that do not see the errors: p ≤ 0.05
    in at most 6 % of 2000 draws (the plain day test's bar), and not degenerate."""
    rng = np.random.default_rng(21 + days + int(10 * phi_d) + 100 * zeros)
    lab = np.repeat(np.arange(days), 4)
    p = np.array([sig.day_p(_day_null(rng, days, phi_d), lab, weights=_weights(rng, days, zeros))
                  for _ in range(2000)])
    assert np.mean(p <= 0.05) <= 0.06, np.mean(p <= 0.05)
    assert 0.35 <= np.mean(p <= 0.5) <= 0.65, np.mean(p <= 0.5)


def test_equal_weights_are_the_plain_day_test():
    rng = np.random.default_rng(22)
    lab = np.repeat(np.arange(7), 4)
    for _ in range(50):
        d = 0.1 + _day_null(rng, 7, 0.3)
        assert sig.day_p(d, lab, weights=np.full(7, 2.5)) == pytest.approx(sig.day_p(d, lab),
                                                                           abs=1e-12)
    gap = lab + (lab >= 3)  # a gap counts as a day in the correlation, as in the plain test
    assert sig.day_p(d, gap, weights=np.ones(7)) == pytest.approx(sig.day_p(d, gap), abs=1e-12)


def test_too_few_weighted_days_give_no_evidence():
    lab = np.repeat(np.arange(7), 4)
    d = np.full(28, 0.5) + 0.01 * np.arange(28)
    assert sig.day_p(d, lab, weights=np.array([0, 0, 1.0, 0, 0, 2.0, 0])) == 1.0
    assert sig.day_p(d, lab, weights=np.zeros(7)) == 1.0


def test_a_cut_that_follows_the_weights_is_found_more_often():
    """An effect that acts on some days only (its cut ∝ the change it predicts there), the
    same day-correlated scatter: the weighted test finds it more often than the plain one."""
    rng = np.random.default_rng(23)
    lab = np.repeat(np.arange(7), 4)
    hits = np.zeros(2)
    for _ in range(500):
        w = _weights(rng, 7, zeros=False)
        d = 0.25 * np.repeat(w / w.mean(), 4) + 0.3 * _day_null(rng, 7, sig.DAY_RHO)
        hits += [sig.day_p(d, lab) <= 0.05, sig.day_p(d, lab, weights=w) <= 0.05]
    plain, weighted = hits / 500
    assert weighted >= plain + 0.05, (plain, weighted)


def _judged(monkeypatch, on: bool):
    """7 held-out days after a 7-day calibration part: the reference 1 K off, the candidate
    predicting a change of 0.6 K on days 1, 2 and 5 only and cutting the error there."""
    dt, s = 300.0, int(7 * 86400 / 300.0)
    n_h = int(7 * 86400 / dt)
    acts = np.repeat(np.isin(np.arange(7), [1, 2, 5]), int(86400 / dt))
    rng = np.random.default_rng(5)
    meas = np.zeros(s + n_h)
    before = {"free_run": 1.0 + 0.2 * np.repeat(rng.normal(size=7 * 4), int(6 * 3600 / dt))}
    after = {"free_run": before["free_run"] - 0.6 * acts}
    monkeypatch.setattr(jd, "DAY_WEIGHTS", on)
    return jd.judge(before, before, after, meas, jd.heldout_blocks(s, s + n_h, dt), s, dt,
                    [0.0], jd.last_start(14 * 86400.0, 7 * 86400.0))


def test_the_judge_weights_each_day_by_the_candidates_own_change(monkeypatch):
    off = _judged(monkeypatch, False)
    assert "day_weights" not in off.stats and off.p == off.stats["p_days"]
    on = _judged(monkeypatch, True)
    assert on.stats["day_weights"] == pytest.approx([0, 0.6, 0.6, 0, 0, 0.6, 0], abs=1e-12)
    assert on.p == on.stats["p_days_weighted"] < on.stats["p_days"]
    assert on.stats["p_days"] == off.stats["p_days"]

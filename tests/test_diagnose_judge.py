"""The judge (gateway/diagnose/judge.py): its null calibration and its guards, on synthetic
held-out errors (fast; the end-to-end false-alarm promise is tests/test_diagnose_false_alarm.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import judge as jd
from gateway.diagnose import significance as sig
from gateway.diagnose.bic import delta_bic, effective_samples


def _ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    e = rng.normal(size=n)
    out = np.empty(n)
    out[0] = e[0] / np.sqrt(1 - phi**2)
    for i in range(1, n):
        out[i] = phi * out[i - 1] + e[i]
    return out


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.8])
def test_paired_p_has_its_nominal_size_under_the_null(phi):
    """28 pieces (7 held-out days of 6-h pieces), differences of mean zero, correlated from
    piece to piece as the weather makes them: p ≤ α in about α of the draws; at the per-
    candidate level of the rule (5 % / 7) within a factor 3."""
    rng = np.random.default_rng(1)
    p = np.array([sig.paired_p(_ar1(rng, 28, phi)) for _ in range(2000)])
    assert np.mean(p <= 0.05) <= 0.065, np.mean(p <= 0.05)
    assert np.mean(p <= 0.2) <= 0.22, np.mean(p <= 0.2)
    assert np.mean(p <= jd.ALPHA / 7) <= 3 * jd.ALPHA / 7, np.mean(p <= jd.ALPHA / 7)
    assert np.mean(p <= 0.5) == pytest.approx(0.5, abs=0.05)  # not degenerate either


def _mean_only_p(d: np.ndarray) -> float:
    """The test before issue 10's detrending: r about the mean, Kendall's (1 + 4r)/n."""
    n = len(d)
    z = d - d.mean()
    r = float(z[1:] @ z[:-1]) / float(z @ z)
    r = min(max(r + (1.0 + 4.0 * r) / n, 0.0), 0.9)
    n_eff = n * (1.0 - r) / (1.0 + r)
    return sig.student_t_sf(float(d.mean() / (np.std(d, ddof=1) / np.sqrt(n_eff))),
                           max(n_eff - 1.0, 1.0))


@pytest.mark.parametrize(("n", "phi"), [(16, 0.5), (16, 0.8), (20, 0.8)])
def test_detrended_autocorrelation_is_no_less_conservative(n, phi):
    """From ``DETREND_MIN_PIECES`` pieces r is read about a line in time: on null differences
    its size is not above the mean-only estimate's (same draws; 0.5 % of slack for the draws)."""
    assert n >= sig.DETREND_MIN_PIECES
    rng = np.random.default_rng(7)
    draws = [_ar1(rng, n, phi) for _ in range(2000)]
    new = np.mean([sig.paired_p(d) <= 0.05 for d in draws])
    old = np.mean([_mean_only_p(d) <= 0.05 for d in draws])
    assert new <= old + 0.005, (new, old)
    assert new <= 0.08, new


def test_a_gain_growing_in_time_is_significant():
    """A drift's gain grows over the held-out week: every piece better, more and more. Read as
    autocorrelation the trend made it insignificant; about a line it is not."""
    rng = np.random.default_rng(8)
    draws = [0.1 + 0.05 * np.arange(28) + 0.3 * _ar1(rng, 28, 0.5) for _ in range(400)]
    new = np.mean([sig.paired_p(d) <= 0.05 for d in draws])
    old = np.mean([_mean_only_p(d) <= 0.05 for d in draws])
    assert new >= 0.75 and old <= 0.5, (new, old)


def test_few_pieces_keep_the_mean_only_estimate():
    rng = np.random.default_rng(9)
    d = 0.3 + _ar1(rng, sig.DETREND_MIN_PIECES - 1, 0.5)
    assert sig.paired_p(d) == pytest.approx(_mean_only_p(d))


def test_student_t_tail_matches_published_quantiles():
    # one-sided critical values of Student's t (any table): df 6 → 1.943 (5 %), 3.143 (1 %),
    # 3.707 (0.5 %); df 1 → 6.314 (5 %); df 30 → 1.697 (5 %)
    for t, df, p in ((1.943, 6, 0.05), (3.143, 6, 0.01), (3.707, 6, 0.005), (6.314, 1, 0.05),
                     (1.697, 30, 0.05)):
        assert sig.student_t_sf(t, df) == pytest.approx(p, rel=2e-3)
    assert sig.student_t_sf(0.0, 5) == pytest.approx(0.5)
    assert sig.student_t_sf(-1.943, 6) == pytest.approx(0.95, rel=1e-3)


def test_paired_p_sees_a_real_improvement():
    rng = np.random.default_rng(2)
    d = 0.8 + _ar1(rng, 28, 0.5) * 0.5
    assert sig.paired_p(d) < 0.001


END = 14 * 86400.0
LAST = jd.last_start(END, 7 * 86400.0)


def _case(cut_per_piece: np.ndarray, dt: float = 300.0, noise: float = 0.0):
    """Held-out errors over 7 days after a 7-day calibration part: the model before and the
    reference are 1 K off, the model after lower by ``cut`` per 6-h piece."""
    piece = int(jd.JUDGE_PIECE_S / dt)
    n_h = piece * len(cut_per_piece)
    s = int(7 * 86400 / dt)
    rng = np.random.default_rng(4)
    meas = np.zeros(s + n_h)
    before = {"free_run": 1.0 + noise * rng.normal(size=n_h)}
    after = {"free_run": np.repeat(1.0 - cut_per_piece, piece) + noise * rng.normal(size=n_h)}
    return before, after, meas, jd.heldout_blocks(s, s + n_h, dt), s


def test_a_lasting_significant_change_passes_and_a_spell_does_not():
    rng = np.random.default_rng(3)
    lasting = np.clip(0.3 + 0.05 * rng.normal(size=28), 0, 1)
    before, after, meas, blocks, s = _case(lasting)
    v = jd.judge(before, before, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert v.ok, v.why
    spell = np.where(np.arange(28) < 10, 0.6, 0.0)  # better only over the first 2.5 days
    before, after, meas, blocks, s = _case(spell)
    v = jd.judge(before, before, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert not v.ok and "both halves" in v.why


def test_small_or_insignificant_cuts_do_not_pass():
    before, after, meas, blocks, s = _case(np.full(28, 0.15))  # 15 %: below the size asked
    assert not jd.judge(before, before, after, meas, blocks, s, 300.0, [0.0], LAST).ok
    rng = np.random.default_rng(5)
    noisy = 0.25 + 1.5 * _ar1(rng, 28, 0.5)  # 25 % on average, but from a few pieces
    before, after, meas, blocks, s = _case(noisy)
    v = jd.judge(before, before, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert v.p > jd.ALPHA and not v.ok


def test_a_change_in_the_last_days_does_not_pass():
    before, after, meas, blocks, s = _case(np.full(28, 0.3))
    assert LAST == END - 3 * 86400.0  # three days must follow a start
    v = jd.judge(before, before, after, meas, blocks, s, 300.0, [END - 60 * 3600.0], LAST)
    assert not v.ok and "end of the data" in v.why
    assert jd.last_start(6 * 86400.0, 3 * 86400.0) == 4.5 * 86400.0  # half a short held-out part


def test_the_reference_refit_takes_its_own_share():
    """An effect that is no better than the base refitted on the same data does not pass,
    however much it beats the base as calibrated."""
    before, after, meas, blocks, s = _case(np.full(28, 0.3))
    v = jd.judge(before, after, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert not v.ok and v.gain == pytest.approx(0.3)


def test_the_reference_test_rejects_a_fading_spell_the_refit_leaves(monkeypatch):
    """A base that does not carry over leaves a spell the refit without the effect takes only
    in part: the candidate beats the model before on every day (p ~ 0), the reference by 36 %
    overall and positively in both halves, but by 0.5 K on the first 3 days and 0.02 K after.
    Main's rule passes it; with ``REFERENCE_TEST`` its days against the reference are not
    significant and it is rejected saying so. A cut against the reference that lasts passes."""
    piece = int(jd.JUDGE_PIECE_S / 300.0)
    before, after, meas, blocks, s = _case(np.full(28, 0.6))
    fading = {"free_run": after["free_run"] + np.repeat(np.where(np.arange(28) < 12, 0.5, 0.02),
                                                         piece)}
    assert not jd.REFERENCE_TEST  # off: main's rule
    v = jd.judge(before, fading, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert v.ok and v.stats["p"] < 1e-6 and min(v.stats["halves"]) > 0
    assert v.stats["cut_reference"] > jd.MIN_REF_CUT and v.stats["p_days_reference"] > jd.ALPHA
    monkeypatch.setattr(jd, "REFERENCE_TEST", True)
    v = jd.judge(before, fading, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert not v.ok and "not significant against the reference" in v.why, v.why
    rng = np.random.default_rng(3)
    lasting = {"free_run": after["free_run"] + np.repeat(0.2 + 0.05 * rng.normal(size=28), piece)}
    v = jd.judge(before, lasting, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert v.ok and v.stats["p_days_reference"] <= jd.ALPHA, v.why


def test_one_delta_bic():
    n_e = effective_samples(7200, 60.0)  # 5 days of 1-minute residuals: 120 effective samples
    assert n_e == pytest.approx(120.0)
    assert delta_bic(1.0, 1.0, n_e, 2) == pytest.approx(2 * np.log(120.0))
    assert delta_bic(0.5, 1.0, n_e, 1) == pytest.approx(120 * np.log(0.5) + np.log(120.0))
    assert effective_samples(3, 60.0) == 2.0


def _day_null(rng: np.random.Generator, days: int, phi_d: float, share: float) -> np.ndarray:
    """Null piece differences with day-scale dependence: a day effect, AR(1) across days
    (``phi_d``), carrying ``share`` of the variance, shared by the day's 4 pieces of 6 h, plus
    piece noise: the base's error on the dev windows is correlated over whole days."""
    u = _ar1(rng, days, phi_d) * np.sqrt(1 - phi_d**2)
    return np.sqrt(share) * np.repeat(u, 4) + np.sqrt(1 - share) * rng.normal(size=4 * days)


DAYS7 = np.repeat(np.arange(7), 4)


def test_the_piece_test_is_anti_conservative_under_day_scale_dependence():
    """Why ``day_p`` exists: the pieces' lag-1 autocorrelation understates a dependence that
    lasts whole days and spells of days (measured: 14-16 % at a nominal 5 % for day-to-day
    correlation 0.5, docs/effects.md "False alarms")."""
    rng = np.random.default_rng(11)
    p = np.array([sig.paired_p(_day_null(rng, 7, 0.5, 0.6)) for _ in range(2000)])
    assert np.mean(p <= 0.05) >= 0.10, np.mean(p <= 0.05)


@pytest.mark.parametrize(("phi_d", "share"), [(0.0, 0.9), (0.3, 0.6), (sig.DAY_RHO, 0.6),
                                              (sig.DAY_RHO, 0.9)])
def test_day_p_holds_its_size_on_day_correlated_nulls(phi_d, share):
    """7 held-out days x 4 pieces, day-to-day correlation up to the one it is built for
    (``DAY_RHO``): p ≤ 0.05 in at most ~6 % of the draws, and not degenerate."""
    rng = np.random.default_rng(12)
    p = np.array([sig.day_p(_day_null(rng, 7, phi_d, share), DAYS7, sig.DAY_RHO)
                  for _ in range(2000)])
    assert np.mean(p <= 0.05) <= 0.06, np.mean(p <= 0.05)
    assert np.mean(p <= 0.5) == pytest.approx(0.5, abs=0.05)


def test_day_p_finds_a_consistent_daily_cut():
    """An effect cuts the error on every day after its start: found on 7 days and on 4, with
    the same day-correlated scatter as the null above."""
    rng = np.random.default_rng(13)
    for days in (7, 4):
        lab = np.repeat(np.arange(days), 4)
        p = np.array([sig.day_p(0.3 + 0.1 * _day_null(rng, days, sig.DAY_RHO, 0.6), lab)
                      for _ in range(400)])
        assert np.mean(p <= 0.05) >= 0.9, (days, np.mean(p <= 0.05))


def test_day_p_units_are_days():
    """Pieces of one day are one unit (their order within the day does not matter), a day
    without a comparable piece is a gap, fewer than 3 days give no evidence."""
    rng = np.random.default_rng(14)
    d = 0.2 + 0.3 * rng.normal(size=28)
    shuffled = np.concatenate([rng.permutation(d[4 * k : 4 * k + 4]) for k in range(7)])
    assert sig.day_p(d, DAYS7) == pytest.approx(sig.day_p(shuffled, DAYS7))
    assert sig.day_p(d[:8], DAYS7[:8]) == 1.0
    gap = DAYS7 + (DAYS7 >= 3)  # no day 3
    assert sig.day_p(d, gap) != pytest.approx(sig.day_p(d, DAYS7))


def test_the_switch_judges_on_days(monkeypatch):
    """With ``DAY_TEST`` on the verdict's p is the days' (both are logged either way), and a
    lasting cut still passes."""
    rng = np.random.default_rng(3)
    before, after, meas, blocks, s = _case(np.clip(0.3 + 0.05 * rng.normal(size=28), 0, 1))
    assert jd.DAY_TEST  # shipped on (2026-11-27)
    monkeypatch.setattr(jd, "DAY_TEST", False)
    off = jd.judge(before, before, after, meas, blocks, s, 300.0, [0.0], LAST)
    monkeypatch.setattr(jd, "DAY_TEST", True)
    on = jd.judge(before, before, after, meas, blocks, s, 300.0, [0.0], LAST)
    assert off.p == off.stats["p_pieces"] and on.p == on.stats["p_days"] == off.stats["p_days"]
    assert len(on.stats["day_means"]) == 7 and on.ok and "7 days" in on.why


def test_a_change_with_too_few_days_after_it_cannot_be_judged_yet(monkeypatch):
    """Under the day test a start leaving 2 held-out days is not "p = 1.000 over 2 days" but
    plainly not judged yet; both p-values are still logged, and the piece test (off) would
    have judged the same 7 pieces."""
    rng = np.random.default_rng(6)
    before, after, meas, blocks, s = _case(np.clip(0.3 + 0.05 * rng.normal(size=28), 0, 1))
    start = END - 1.8 * 86400.0  # day 12.2 of 14: pieces after it on days 12 and 13
    v = jd.judge(before, before, after, meas, blocks, s, 300.0, [start], END)
    assert not v.ok and not v.stats["late"]
    assert v.why.startswith("cannot be judged yet: only 2 held-out days after its start, and a "
                            "change is judged once 3 days of it are held out"), v.why
    assert "p = " not in v.why  # a p of 1 from no days is no evidence either way
    assert v.p == v.stats["p"] == v.stats["p_days"] == 1.0 and len(v.stats["day_means"]) == 2
    assert v.stats["p_pieces"] <= jd.ALPHA and v.stats["pieces"] == 7
    monkeypatch.setattr(jd, "DAY_TEST", False)
    off = jd.judge(before, before, after, meas, blocks, s, 300.0, [start], END)
    assert off.ok and "over the 7 pieces of 6 h after its start" in off.why, off.why
    assert off.stats["p_days"] == 1.0 and off.p == off.stats["p_pieces"]

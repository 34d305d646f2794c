"""The bg study's day-block bootstrap and its rule's verdict (tests/generality/bagged_base.py)."""

from __future__ import annotations

import numpy as np

from tests.generality.bagged_base import day_counts, day_resample, verdict, voted


def test_day_counts_draw_as_many_days_as_there_are_reproducibly():
    counts = [day_counts(7, b) for b in range(5)]
    assert all(c.shape == (7,) and c.sum() == 7 and (c >= 0).all() for c in counts)
    np.testing.assert_array_equal(day_counts(7, 3), counts[3])
    assert len({tuple(c) for c in counts}) > 1  # the seed moves the draw


def test_day_resample_keeps_drawn_days_windows_as_often_as_drawn():
    dt = 300.0  # 288 rows a day
    counts = np.array([2, 0, 1])
    starts = np.array([72, 144, 288, 360, 576, 648])  # two windows on each day
    got = day_resample(counts, dt)(starts)
    np.testing.assert_array_equal(got, [72, 72, 144, 144, 576, 648])
    assert day_resample(np.zeros(3, dtype=int), dt)(starts).size == 0


def record(gen: str, main: float, cand: float) -> dict:
    return {"generator": gen, "main": {"mae": main}, "cand": {"mae": cand},
            "change_pct": 100.0 * (cand / main - 1.0)}


def test_verdict_applies_the_three_criteria():
    good = [record("a", 1.0, 0.9), record("b", 1.0, 0.9)]
    v = verdict(good)
    assert v["a"] and v["b"] and v["c"] and v["step1_passes"]
    # pooled -10 % but generator b worse
    v = verdict([record("a", 1.0, 0.7), record("b", 1.0, 1.1)])
    assert v["a"] and not v["b"] and not v["step1_passes"]
    # pooled falls enough, both generators better, but 4 windows worse by > 10 %
    recs = [record("a", 1.0, 1.11) for _ in range(2)] + [record("b", 1.0, 1.11) for _ in range(2)]
    recs += [record("a", 2.0, 1.0), record("b", 2.0, 1.0)]
    v = verdict(recs)
    assert v["worse_10pct"] == 4 and v["a"] and v["b"] and not v["c"]
    # pooled -4 %: (a) fails
    assert not verdict([record("a", 1.0, 0.96), record("b", 1.0, 0.96)])["a"]


def test_voted_keeps_the_parts_a_majority_of_the_bags_kept():
    bags = [["heat store"], ["heat store", "sensor offset"], ["sensor offset"], ["heat store"], []]
    rec = {"cand": {"bags": [{"kept": k} for k in bags]}}
    assert voted(rec) == {"heat store"}  # 3 of 5; the offset's 2 of 5 is no majority
    assert voted(rec, bags=4) == {"heat store"}
    assert voted({"cand": {"bags": [{"kept": []}] * 5}}) == set()

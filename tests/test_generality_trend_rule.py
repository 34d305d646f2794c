"""The ft rule's scoring (tests/generality/trend_rule.py) on made-up horizons: each of its
four conditions is read from the right cells."""

from __future__ import annotations

from tests.generality.trend_rule import verdict, window_goals


def _hs(corr: dict[int, float], outlook: dict[int, float], pers: float = 1.0, arx: float = 0.8):
    return {m: {"persistence": {"mae": pers}, "arx": {"mae": arx}, "corrected": {"mae": corr[m]},
                "corrected_outlook": {"mae": outlook[m]}} for m in (15, 30, 60)}


GOOD = {15: 0.6, 30: 0.6, 60: 0.6}
MISS15 = {15: 0.75, 30: 0.6, 60: 0.6}


def test_window_goals_read_every_horizon_and_the_outlook_from_30_min():
    assert window_goals(_hs(GOOD, {15: 0.99, 30: 0.7, 60: 0.7})) == (True, True)
    assert window_goals(_hs(MISS15, {15: 0.5, 30: 0.7, 60: 0.9})) == (False, False)


def test_a_window_gained_with_no_cell_worse_passes():
    rows = [("a", _hs(MISS15, GOOD), _hs(GOOD, GOOD)), ("b", _hs(GOOD, GOOD), _hs(GOOD, GOOD))]
    ok, lines = verdict(rows)
    assert ok and "verdict: PASSES" in lines[-1]


def test_no_window_gained_fails_even_when_every_cell_is_better():
    better = {m: 0.74 for m in (15, 30, 60)}
    ok, _ = verdict([("a", _hs(MISS15, GOOD), _hs({15: 0.72, 30: 0.59, 60: 0.59}, GOOD)),
                     ("b", _hs(better, GOOD), _hs(better, GOOD))])
    assert not ok


def test_one_cell_worse_by_more_than_3_percent_fails():
    worse = {15: 0.6, 30: 0.6, 60: 0.62}
    ok, lines = verdict([("a", _hs(MISS15, GOOD), _hs(GOOD, GOOD)), ("b", _hs(GOOD, GOOD), _hs(worse, GOOD))])
    assert not ok and any("(d)" in line and "✗" in line for line in lines)

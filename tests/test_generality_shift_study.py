"""tests/generality/shift_study.py: the cw rule's step-1 verdict on made-up windows (no
generator runs)."""

from __future__ import annotations

from tests.generality.shift_study import verdict


def records(changes: dict[str, list[float]], main: float = 1.0) -> list[dict]:
    """Windows of MAE ``main`` [K] whose candidate changes by the given fractions."""
    return [{"generator": g, "window": f"w{i}", "main": {"mae": main},
             "cand": {"mae": main * (1.0 + c)}, "change_pct": 100.0 * c}
            for g, cs in changes.items() for i, c in enumerate(cs)]


def test_a_broad_cut_passes_all_three() -> None:
    v = verdict(records({"refsim": [-0.1] * 10, "twonode": [-0.06] * 10}))
    assert v["a"] and v["b"] and v["c"] and v["step1_passes"]
    assert abs(v["pooled_change_pct"] + 8.0) < 1e-9


def test_one_generator_rising_fails_b_even_with_a_pooled_cut() -> None:
    v = verdict(records({"refsim": [-0.2] * 10, "twonode": [0.01] * 10}))
    assert v["a"] and not v["b"] and not v["step1_passes"]


def test_four_windows_worse_by_more_than_ten_percent_fail_c() -> None:
    v = verdict(records({"refsim": [0.11] * 4 + [-0.3] * 6, "twonode": [-0.1] * 10}))
    assert v["a"] and v["b"] and v["worse_10pct"] == 4 and not v["c"]
    v3 = verdict(records({"refsim": [0.11] * 3 + [-0.3] * 7, "twonode": [-0.1] * 10}))
    assert v3["c"] and v3["step1_passes"]


def test_a_small_pooled_cut_fails_a() -> None:
    v = verdict(records({"refsim": [-0.04] * 10, "twonode": [-0.04] * 10}))
    assert not v["a"] and v["b"] and v["c"] and not v["step1_passes"]

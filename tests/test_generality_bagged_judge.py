"""Rule bq's verdict from the suite's results (tests/generality/bagged_judge.py)."""

from __future__ import annotations

from tests.generality.bagged_judge import verdict
from tests.generality.generators import KINDS, OUTSIDE

EXTRA = ("e1", "e2", "e3", "e4", "e5", "e6", "e7")


def row(g: str, w: str, kind: str, ok: bool) -> dict:
    return {"case": {"generator": g, "window": w, "kind": kind},
            "verdict": {"ok": ok}, "before": 1.0, "findings": []}


def suite(passing: dict[tuple[str, str], int], alarms: dict[str, int],
          unexplained: dict[tuple[str, str], int]) -> dict[tuple, dict]:
    """Results: on each (generator, window) the first ``passing`` of the 7 library changes pass
    (the two heaters count as one kind), ``unexplained`` of the 2 outside ones are flagged, and
    ``alarms`` of a generator's 10 effect-free windows have a finding."""
    out = {}
    for g in ("refsim", "twonode"):
        for w in ("autumn", "winter", "summer"):
            n = passing[(g, w)]
            for i, k in enumerate(KINDS):
                out[(g, w, k)] = row(g, w, k, i < n)
            for i, k in enumerate(OUTSIDE):
                out[(g, w, k)] = row(g, w, k, i < unexplained[(g, w)])
        for i, w in enumerate(("autumn", "winter", "summer") + EXTRA):
            out[(g, w, "none")] = row(g, w, "none", i >= alarms[g])
    return out


def grid(v: int) -> dict[tuple[str, str], int]:
    return {(g, w): v for g in ("refsim", "twonode") for w in ("autumn", "winter", "summer")}


def test_verdict_applies_the_four_criteria():
    main = suite(grid(3), {"refsim": 1, "twonode": 0}, grid(1))
    better = grid(3) | {("refsim", "autumn"): 5}  # kinds 2, 3 and 4 (both heaters) pass too
    v = verdict(main, suite(better, {"refsim": 1, "twonode": 1}, grid(1)))
    assert (v["kinds_main"], v["kinds_bagged"]) == (12, 14)
    assert v["a"] and v["b"] and v["c"] and v["d"] and v["passes"] and not v["partial"]
    # one more false alarm on twonode: 8 of 10 quiet, (a) fails
    v = verdict(main, suite(better, {"refsim": 1, "twonode": 2}, grid(1)))
    assert v["a"] is False and v["passes"] is False
    # +2 kinds overall but one window falls by 2: (c) fails
    mixed = better | {("twonode", "summer"): 5, ("refsim", "winter"): 0}
    v = verdict(main, suite(mixed, {"refsim": 0, "twonode": 0}, grid(1)))
    assert v["b"] and v["c"] is False and not v["passes"]
    # two fewer unexplained: (d) fails
    fewer = grid(1) | {("refsim", "autumn"): 0, ("twonode", "autumn"): 0}
    v = verdict(main, suite(better, {"refsim": 0, "twonode": 0}, fewer))
    assert v["unexplained_main"] - v["unexplained_bagged"] == 2 and v["d"] is False


def test_a_partial_run_is_undecided_unless_a_final_criterion_failed():
    main = suite(grid(3), {"refsim": 0, "twonode": 0}, grid(1))
    part = {k: r for k, r in suite(grid(3), {"refsim": 0, "twonode": 0}, grid(1)).items()
            if k[1] != "summer" or k[2] == "none"}
    v = verdict(main, part)
    assert v["partial"] and v["missing"] == ["refsim/summer", "twonode/summer"]
    assert v["b"] is False and v["passes"] is None  # summer could still add the kinds
    worse = {k: r for k, r in suite(grid(3) | {("refsim", "autumn"): 0},
                                    {"refsim": 0, "twonode": 0}, grid(1)).items()
             if k[1] != "summer" or k[2] == "none"}
    assert verdict(main, worse)["passes"] is False  # refsim autumn fell by 2: final

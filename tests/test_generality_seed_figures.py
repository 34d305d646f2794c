"""tests/generality/seed_figures.py on made-up suite rows: the per-run figures, one arm's seed
noise, and two arms compared over seed pairs."""

from __future__ import annotations

import json

import pytest

from tests.generality.seed_figures import diagnose_rows, figures, noise, over_pairs, verdict_lines


def _row(gen: str, window: str, kind: str, ok: bool, seed: int = 1, invisible: bool = False) -> dict:
    v = {"ok": ok}
    if kind == "none" or invisible:
        v["false_alarm"] = not ok
    if invisible:
        v["invisible"] = True
    return {"case": {"task": "diagnose", "generator": gen, "window": window, "kind": kind,
                     "seed": seed}, "verdict": v}


def _run(heater_ok: bool, quiet: int, seed: int = 1) -> list[dict]:
    rows = [_row("refsim", "autumn", "heater", heater_ok, seed),
            _row("refsim", "autumn", "night_heater", True, seed),
            _row("refsim", "autumn", "drift", True, seed),
            _row("refsim", "winter", "ventilation", False, seed, invisible=True)]
    rows += [_row("refsim", f"w{i}", "none", i < quiet, seed) for i in range(10)]
    return rows


def test_figures_count_kinds_quiet_windows_and_passes():
    f = figures(_run(heater_ok=False, quiet=9))
    assert f["kinds"][("refsim", "autumn")] == (1, 6)  # drift; heater needs both its cases
    assert f["kinds"][("refsim", "winter")] == (0, 5)  # ventilation invisible: not judged
    assert f["quiet"]["refsim"] == (9, 10)
    assert f["passes"] == 2 + 9 and f["cases"] == 14


def test_noise_and_pairs():
    a1, a2 = figures(_run(False, 10)), figures(_run(True, 9))
    n = noise([a1, a2])
    assert n["range"][("refsim", "autumn")] == 1 and n["range"][("refsim", "winter")] == 0
    assert n["flips"] == [("refsim", "autumn", "heater"), ("refsim", "w9", "none")]
    o = over_pairs([(a1, a2), (a2, a2)])
    assert (o["kinds_a"], o["kinds_b"]) == (1 + 2, 2 + 2)
    assert (o["quiet_a"], o["quiet_b"], o["fewest_quiet_b"]) == (19, 18, 9)


def test_one_seed_per_results_file(tmp_path):
    p = tmp_path / "r.json"
    p.write_text(json.dumps({"results": _run(True, 10, seed=3)}), encoding="utf-8")
    seed, rows = diagnose_rows(p)
    assert seed == 3 and len(rows) == 14
    p.write_text(json.dumps({"results": _run(True, 10, 3) + _run(True, 10, 2)}), encoding="utf-8")
    with pytest.raises(ValueError, match="seeds"):
        diagnose_rows(p)


def test_verdict_lines_list_the_cases_that_differ():
    lines = verdict_lines([("a", figures(_run(False, 10))), ("b", figures(_run(True, 9)))])
    assert "| refsim/autumn/heater | n | y |" in lines and "| refsim/w9/none | y | n |" in lines
    assert lines[-1] == "\nthe other 12 cases: 11 pass and 1 fail in every run"

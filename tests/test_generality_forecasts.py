"""The forecast suite's tables (tests/generality/forecasts.py): goal marks and the per-window
summary, on made-up figures."""

from __future__ import annotations

from tests.generality.forecasts import COLUMNS, goals, markdown, summary


def _case(generator: str, window: str, mae: dict[str, float]) -> dict:
    names = [k for k, _ in COLUMNS]
    horizons = {}
    for minutes in ("15", "30", "60"):
        horizons[minutes] = {k: {"mae": mae.get(k, 1.0)} for k in names}
    return {"case": {"kind": "forecast", "generator": generator, "window": window},
            "horizons": horizons}


def test_goals_and_the_per_window_summary():
    good = {"persistence": 1.0, "arx": 0.8, "corrected": 0.6, "corrected_outlook": 0.75}
    poor = {"persistence": 1.0, "arx": 0.8, "corrected": 0.75, "corrected_outlook": 0.85}
    results = [_case("refsim", "winter", good), _case("vanthoor", "summer", poor)]
    h = results[0]["horizons"]
    assert goals(h["15"], "corrected", 15) == (True, None)
    assert goals(h["60"], "corrected", 60) == (True, True)
    assert goals(results[1]["horizons"]["60"], "corrected", 60) == (False, False)
    text = summary(results)
    row = next(line for line in text.splitlines() if line.startswith("| corrected |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "2 / 2 (held out 1 / 1): refsim winter; vanthoor summer"  # beats the ARX
    assert cells[3] == "1 / 2 (held out 0 / 1): refsim winter"  # measured-weather goal
    assert cells[4] == "1 / 2 (held out 0 / 1): refsim winter"  # outlook goal
    assert "vanthoor (held out) | summer | 60" in markdown(results)


def test_compare_marks_better_worse_and_the_goal(tmp_path):
    import json

    from tests.generality.compare_forecasts import table

    before = {"persistence": 1.0, "arx": 0.8, "corrected": 0.75, "adaptive": 0.5}
    after = {**before, "corrected": 0.6, "adaptive": 0.6}
    paths = []
    for name, mae in (("a", before), ("b", after)):
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps({"results": [_case("refsim", "summer", mae)]}), encoding="utf-8")
        paths.append(str(p))
    rows = [r for r in table(*paths, ["adaptive", "corrected"]).splitlines() if r.startswith("| refsim")]
    assert len(rows) == 3
    assert rows[0] == ("| refsim summer | 15 | 1.000 | 0.800 | 0.500 → 0.600 ⬆ | 0.750 → 0.600 ⬇ "
                       "| ✗ → ✓ |")

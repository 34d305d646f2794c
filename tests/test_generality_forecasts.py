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


def test_the_ol_rule_counts_goals_the_mean_and_the_worst_cell():
    from tests.generality.outlook_rule import verdict

    def win(outlook: float, corrected: float = 0.6) -> dict:
        return _case("refsim", "winter", {"persistence": 1.0, "arx": 0.8, "corrected": corrected,
                                          "corrected_outlook": outlook})["horizons"]

    main = {"refsim winter": win(0.82), "twonode winter": win(0.7)}
    gained = {"refsim winter": win(0.79), "twonode winter": win(0.7)}  # a goal won, -1.8 %
    ok, lines = verdict(main, gained)
    assert ok and "outlook goals met: 1 → 2 of 2; a goal met by main lost: False" in lines
    lost = {"refsim winter": win(0.5), "twonode winter": win(0.81)}  # mean -20 %, a goal lost
    assert not verdict(main, lost)[0]
    small = {"refsim winter": win(0.81), "twonode winter": win(0.68)}  # -2.0 %: neither branch
    assert not verdict(main, small)[0]
    worse_cell = {"refsim winter": win(0.72), "twonode winter": win(0.72)}  # +2.9 % on one window
    ok, lines = verdict(main, worse_cell)
    assert not ok and lines[-2].endswith("NOT met")
    moved = {"refsim winter": win(0.6, 0.61), "twonode winter": win(0.6)}  # corrected moved 1.7 %
    assert not verdict(main, moved)[0]

"""``make run``'s summary.json is strict JSON, whatever the run scored (training/appliance/summary.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.status.snapshot import Skill
from training.appliance.summary import Summary


def refuse(constant: str) -> None:
    raise ValueError(f"not JSON: {constant}")


def test_a_horizon_not_scored_yet_is_null_not_nan(tmp_path: Path) -> None:
    """A short run scores the 15-min forecasts only: the 30 and 60 min had NaN MAEs, written as
    NaN (Python's json), which strict parsers refuse."""
    s = Summary(start=1257062520.0, end=1257064380.0, scale=120.0, kit_records=30, stored=30,
                skill=[Skill(15, 13, 0.21, 0.14), Skill(30, 0, float("nan"), float("nan"))])
    s.write_json(tmp_path / "summary.json")
    d = json.loads((tmp_path / "summary.json").read_text(), parse_constant=refuse)
    assert d["skill"] == [{"horizon_min": 15, "n": 13, "mae": 0.21, "persistence_mae": 0.14},
                          {"horizon_min": 30, "n": 0, "mae": None, "persistence_mae": None}]
    assert d["minutes"] == pytest.approx(31.0) and d["kit_records"] == 30


def forecast_line(skill: list[Skill]) -> str:
    s = Summary(start=1257062520.0, end=1257076920.0, scale=120.0, kit_records=240, stored=240,
                skill=skill)
    text = "\n".join(s.lines())
    part = text[text.index("  forecast"):text.index("  findings")]
    return " ".join(part.split())  # the lines wrap at the terminal's width


def test_each_horizon_says_its_own_count_when_they_differ() -> None:
    """A run scores more 15-min forecasts than 60-min ones; one "n = 9" read as every horizon's
    (it was the longest's: "n = 9" beside a 15-min MAE over 24)."""
    line = forecast_line([Skill(15, 24, 0.2, 0.3), Skill(30, 18, 0.3, 0.4), Skill(60, 9, 0.5, 0.6)])
    assert "15 min 0.20 °C (persistence 0.30, n=24)" in line, line
    assert "60 min 0.50 °C (persistence 0.60, n=9)" in line
    assert line.count("n=") == 3
    same = forecast_line([Skill(15, 9, 0.2, 0.3), Skill(60, 9, 0.5, 0.6)])
    assert same.endswith("(persistence 0.60), n=9") and same.count("n=") == 1

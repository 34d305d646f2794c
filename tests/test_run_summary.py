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

"""Which model the gateway's diagnosis runs for each greenhouse's model, and when its hint at
another model becomes a note of the run (gateway/service/diagnosis.py)."""

from __future__ import annotations

from pathlib import Path

from gateway.service.config import parse_config
from gateway.service.diagnosis import diagnose_command


def test_a_vented_greenhouse_is_diagnosed_with_the_prototype(tmp_path: Path) -> None:
    """The live default prototype+vent_control forecasts with the vent term; its diagnosis stays
    the prototype's (whose base chooses that part itself); the other models pass through."""
    cfg = parse_config({
        "gateway": {"farm": "f1", "db": "gw.db", "keys": "keys.txt"},
        "greenhouse": [
            {"name": "north", "greenhouse": "biskra-prototype", "model": "prototype+vent_control",
             "inside": 7},
            {"name": "south", "greenhouse": "biskra-prototype", "model": "prototype", "inside": 8},
            {"name": "east", "greenhouse": "almeria-palmerillas", "model": "almeria", "inside": 9},
            {"name": "west", "greenhouse": "biskra-prototype",
             "model": "prototype+vent_control+heating", "inside": 10}]},
        "test.toml", tmp_path)
    used = {}
    for g in cfg.greenhouses:
        cmd = diagnose_command(g, tmp_path / f"{g.name}.csv")
        assert cmd[1:4] == ["-m", "gateway", "diagnose"] and cmd[-1] == "--json"
        assert cmd[cmd.index("--data") + 1] == str(tmp_path / f"{g.name}.csv")
        used[g.name] = cmd[cmd.index("--model") + 1]
    assert used == {"north": "prototype", "south": "prototype", "east": "almeria",
                    "west": "prototype"}


def test_a_hint_is_a_note_of_the_run_only_when_it_names_another_model() -> None:
    """The diagnosis runs as ``prototype``: its hint to the vented model says nothing to a
    gateway already on it (or on the heated one, which carries the vent term); the hint to the
    heated model does, to a gateway on either of the others."""
    from gateway.model import HEATED_PROTOTYPE, VENTED_PROTOTYPE
    from gateway.service.diagnosis import model_hint_notes

    def said(running: str, hinted: str | None) -> list[str]:
        result = {"hint": f"use {hinted}" if hinted else None, "hint_model": hinted}
        return [n["message"] for n in model_hint_notes(running, result)]

    assert said("prototype", VENTED_PROTOTYPE) == [f"use {VENTED_PROTOTYPE}"]
    assert said(VENTED_PROTOTYPE, VENTED_PROTOTYPE) == []
    assert said(HEATED_PROTOTYPE, VENTED_PROTOTYPE) == []
    assert said("prototype", HEATED_PROTOTYPE) == [f"use {HEATED_PROTOTYPE}"]
    assert said(VENTED_PROTOTYPE, HEATED_PROTOTYPE) == [f"use {HEATED_PROTOTYPE}"]
    assert said(HEATED_PROTOTYPE, HEATED_PROTOTYPE) == []
    assert said("prototype", None) == []
    (note,) = model_hint_notes("prototype", {"hint": "h", "hint_model": HEATED_PROTOTYPE})
    assert note == {"code": "model_hint", "level": "note", "message": "h"}

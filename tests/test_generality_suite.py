"""The generality suite's ``--seed``: it reaches every case, the generator's call and the
visible-size reference (the same window and seed without the change); 1 is the usual suite."""

from __future__ import annotations

import json

import numpy as np

from tests.generality import cases, suite
from tests.generality.cases import Case


def test_all_cases_carry_the_seed():
    default = suite.all_cases()
    seeded = suite.all_cases(seed=3)
    assert {c.seed for c in default} == {1}
    assert {c.seed for c in seeded} == {3}
    assert [Case(**{**c.__dict__, "seed": 1}) for c in seeded] == default  # only the seed differs
    assert len([c for c in seeded if c.task == "diagnose" and c.kind == "none"]) == 3 * 10


def test_the_seed_reaches_the_generator_and_the_visible_reference(monkeypatch):
    seen: list[tuple] = []

    def fake_generate(generator, window, kind="none", seed=1):
        seen.append((generator, kind, seed))
        raise RuntimeError("stop after the call")

    monkeypatch.setattr(cases, "generate", fake_generate)
    monkeypatch.setattr(cases, "window", lambda name: name)
    r = cases.run(Case("diagnose", "refsim", "autumn", "heater", 7))
    assert r["error"] == "RuntimeError: stop after the call"
    assert seen == [("refsim", "heater", 7)]

    refs: list[tuple] = []

    def fake_reference(generator, window_name, seed):
        refs.append((generator, window_name, seed))
        return np.zeros(3)

    monkeypatch.setattr(cases, "_reading_without_change", fake_reference)
    data = type("D", (), {"start": np.datetime64("2009-10-20T00:10"),
                          "time": np.arange("2009-10-20T00:00", "2009-10-20T00:15", 300,
                                            dtype="datetime64[s]"),
                          "columns": {"t_in": np.array([0.0, 0.2, 0.4])}})()
    size = cases.case_visible_change(Case("diagnose", "twonode", "winter", "heater", 7), data)
    assert refs == [("twonode", "winter", 7)]
    assert size == 0.4  # only the reading from the start on


def test_the_seed_option_reaches_the_cases_and_the_results(monkeypatch, tmp_path):
    asked: list[int] = []

    def fake_all_cases(generators, windows, only, kinds, seed=1):
        asked.append(seed)
        return []  # no case to run: the pool starts and ends empty

    monkeypatch.setattr(suite, "all_cases", fake_all_cases)
    out = tmp_path / "r.json"
    assert suite.main(["--jobs", "1", "--no-docs", "--only", "diagnose", "--seed", "2",
                       "--json", str(out)]) == 0
    assert suite.main(["--jobs", "1", "--no-docs", "--json", str(tmp_path / "d.json")]) == 0
    assert asked == [2, 1]
    assert json.loads(out.read_text(encoding="utf-8"))["meta"]["seed"] == 2


def test_forecast_cases_replay_the_shipped_model_and_the_diagnosis_keeps_the_prototype():
    """The forecast rows replay what the live gateway ships (images/gateway/gateway.toml's
    greenhouse model, issue 10 item 3); the diagnosis cases keep the four-parameter prototype."""
    import tomllib

    shipped = tomllib.loads((suite.ROOT / "images" / "gateway" / "gateway.toml").read_text("utf-8"))
    every = suite.all_cases()
    assert {c.model for c in every if c.task == "forecast"} == {shipped["greenhouse"][0]["model"]}
    assert {c.model for c in every if c.task == "diagnose"} == {"prototype"}
    assert cases.FORECAST_MODEL == "prototype+vent_control" != cases.MODEL

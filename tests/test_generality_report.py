"""The generality suite's Markdown (tests/generality/report.py) on made-up results: the earlier
run's summary and base errors beside the new ones, the forecast goals marked on `corrected`."""

from __future__ import annotations

from tests.generality.report import markdown

META = {"command": "make bench-generality", "cases": 3, "minutes": 1.0, "jobs": 1,
        "when": "2026-11-26 17:00 UTC", "commit": "abc1234", "model": "prototype"}


def _free(window: str, base: float, finding: bool) -> dict:
    found = [{"effect": "heat_source", "start": "2009-11-08T16:00:00Z"}] if finding else []
    return {"case": {"task": "diagnose", "generator": "refsim", "window": window, "kind": "none"},
            "findings": found, "verdict": {"ok": not finding, "false_alarm": finding},
            "unexplained": False, "before": base, "after": base, "persistence": 2.0}


def _forecast(corrected: float) -> dict:
    names = ("persistence", "arx", "adaptive", "corrected", "arx_outlook", "adaptive_outlook",
             "corrected_outlook")
    mae = {"persistence": 1.0, "arx": 0.8, "corrected": corrected, "corrected_outlook": 0.75}
    return {"case": {"task": "forecast", "generator": "refsim", "window": "winter", "kind": "none"},
            "horizons": {m: {k: {"mae": mae.get(k, 0.9)} for k in names} for m in ("15", "60")}}


def test_the_earlier_run_stands_beside_and_the_published_forecast_is_marked() -> None:
    after = [_free("autumn", 0.70, False), _free("winter", 0.60, False), _forecast(0.6)]
    before = {"meta": {**META, "commit": "4472d08", "when": "2026-11-23 16:40 UTC"},
              "results": [_free("autumn", 0.73, True), _free("winter", 0.57, False)]}
    text = markdown(after, META, before)
    lines = text.splitlines()
    assert "| refsim | 0/6 | 0/6 | 0/6 | 2 of 2 |" in text  # after: both windows quiet
    was = lines.index(next(x for x in lines if x.startswith("Before (the same suite on commit 4472d08")))
    assert any(x.startswith("| refsim | 0/6 | 0/6 | 0/6 | 1 of 2 |") for x in lines[was:was + 6])
    assert "| autumn | none | 0.700 | 0.730 | 2.000 | no |" in text  # base now, before, persistence
    row = next(x for x in lines if x.startswith("| refsim | winter | 60 |"))
    assert row == "| refsim | winter | 60 | 1.000 | 0.800 | 0.900 | 0.600 | 0.900 | 0.900 | 0.750 | ✓ | ✓ |"
    assert next(x for x in lines if x.startswith("| refsim | winter | 15 |")).endswith("| ✓ |  |")
    assert "Before (" not in markdown(after, META)  # no earlier run: no such table


def _change(kind: str, ok: bool, invisible: bool = False, unexplained: bool = False) -> dict:
    verdict = {"ok": ok, **({"invisible": True, "false_alarm": not ok} if invisible else {})}
    return {"case": {"task": "diagnose", "generator": "refsim", "window": "winter", "kind": kind},
            "findings": [], "verdict": verdict, "unexplained": unexplained, "before": 0.5,
            "after": 0.5, "persistence": 2.0, "visible_k": 0.0 if invisible else 0.4}


def test_a_change_the_data_does_not_show_is_counted_apart() -> None:
    """An invisible kind leaves the kinds' count (x/5), an invisible controller the outside
    library's, and the table says why."""
    rows = [_change("ventilation", True, invisible=True), _change("heater", True),
            _change("night_heater", True), _change("controller", True, invisible=True),
            _change("misting", True, unexplained=True), _free("winter", 0.5, False)]
    text = markdown(rows, META)
    assert ("| refsim | 0/6 | 1/5 | 0/6 | 1 of 1 | 1 of 1 + 1 without a visible change, 1 quiet "
            "(0 of 1) |") in text
    assert "- winter: 1 of 5 effect kinds pass: heater (ventilation: no visible change)" in text
    assert "| winter | controller (no visible change: 0.00 K) | none |" in text

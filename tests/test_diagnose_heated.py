"""The heated-house detector (gateway/diagnose/heated.py) and its hint in ``diagnose``.

Synthetic kit series: an outside that swings by day and from one day to the next, an unheated
house whose air follows 0.85 of it (the two-node house's steady-state share), and a heated one
whose air a proportional thermostat holds near 12 °C whenever it would fall below.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from gateway.diagnose import heated
from gateway.diagnose.heated import heated_floor, night_runs
from gateway.series import Series

STEP = 300.0
SETPOINT = 12.0  # [°C]
GAIN_SHARE = 0.1  # [-] what the thermostat's air still follows of the outside


def kit_columns(days: float, held: bool, seed: int = 0) -> tuple[np.ndarray, dict]:
    """(time, kit columns) of ``days`` days at STEP: daylight 07-17 h UTC."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(days * 86400 / STEP)) * STEP
    hour, day = (t / 3600.0) % 24.0, t / 86400.0
    sun = np.where((hour > 7) & (hour < 17), 400.0 * np.sin(np.pi * (hour - 7) / 10), 0.0)
    t_out = (6.0 + 3.0 * np.sin(2 * np.pi * day / 5) + 3.0 * np.sin(2 * np.pi * (hour - 9) / 24)
             + rng.normal(0, 0.2, t.size))
    t_in = 0.85 * t_out + 2.0 + 0.01 * sun + rng.normal(0, 0.05, t.size)
    if held:
        t_in = np.maximum(t_in, SETPOINT - GAIN_SHARE * (SETPOINT - t_out))
    time = np.datetime64("2009-11-25T00:00:00", "s") + t.astype("timedelta64[s]")
    cols = {"t_in": np.round(t_in, 1), "rh_in": np.full(t.size, 85.0), "t_out": np.round(t_out, 1),
            "rh_out": np.full(t.size, 80.0), "i_glob": np.round(sun), "wind": np.full(t.size, 3.0)}
    return time, cols


def series(days: float = 14.0, held: bool = True, seed: int = 0) -> Series:
    time, cols = kit_columns(days, held, seed)
    return Series(time, STEP, cols)


def test_a_held_floor_is_seen_and_its_level_read():
    f = heated_floor(series(held=True))
    assert f.held and f.nights >= heated.MIN_NIGHTS
    assert f.ratio is not None and f.ratio < heated.MAX_RATIO
    assert f.floor is not None and SETPOINT - 1.5 < f.floor < SETPOINT  # a P band below it
    assert f.lift is not None and f.lift > heated.MIN_LIFT_K


def test_air_that_follows_the_outside_is_not_held():
    f = heated_floor(series(held=False))
    assert not f.held and f.nights >= heated.MIN_NIGHTS
    assert f.ratio is not None and f.ratio > 2 * heated.MAX_RATIO


def test_too_few_nights_decide_nothing():
    f = heated_floor(series(days=4.0, held=True))
    assert not f.held and f.nights < heated.MIN_NIGHTS and f.cold_nights == 0
    assert f.ratio is None and "needs" in f.reason
    assert json.loads(json.dumps(f.to_json()))["ratio"] is None


def test_gaps_and_a_missing_night_leave_the_verdict():
    s = series(held=True)
    rng = np.random.default_rng(1)
    s.columns["t_in"][rng.random(len(s)) < 0.3] = np.nan
    runs = night_runs(s["i_glob"], s.step)
    a, b = runs[3]
    s.columns["t_in"][a:b] = np.nan  # one whole night lost
    f = heated_floor(s)
    assert f.held and f.nights == len(runs) - 1


def test_a_lost_light_reading_does_not_split_a_night():
    s = series(held=True)
    runs = night_runs(s["i_glob"], s.step)
    a, b = runs[2]
    s.columns["i_glob"][(a + b) // 2] = np.nan  # one reading lost mid-night: still one night
    assert night_runs(s["i_glob"], s.step) == runs
    gap = int(4 * 3600 / s.step)  # not bridged (> MAX_GAP_H); each 5-h part is too short a night
    s.columns["i_glob"][(a + b) // 2 - gap // 2:(a + b) // 2 + gap // 2] = np.nan
    assert night_runs(s["i_glob"], s.step) == runs[:2] + runs[3:]


def test_a_night_the_record_cuts_is_left_out():
    s = series(held=True)
    runs = night_runs(s["i_glob"], s.step)
    a, b = runs[-1]
    cut = Series(s.time[:b - 12], s.step, {k: v[:b - 12] for k, v in s.columns.items()})
    assert night_runs(cut["i_glob"], cut.step) == runs[:-1]  # its late part is not in the data
    lost = series(held=True)
    lost.columns["i_glob"][b - 30:] = np.nan  # the sunrise not seen: its end unknown
    assert night_runs(lost["i_glob"], lost.step) == runs[:-1]
    dawn = series(held=True)
    a2, b2 = runs[-2]
    dawn.columns["i_glob"][b2 - 2:b2 + 3] = np.nan  # 25 min lost at sunrise: the readings resume
    assert night_runs(dawn["i_glob"], dawn.step)[-2] == (a2, b2 - 2)


def test_no_light_or_no_inside_reading_is_no_crash():
    s = series(held=True)
    s.columns["i_glob"][:] = np.nan  # never known to be dark: no nights
    assert heated_floor(s).nights == 0 and not heated_floor(s).held
    s = series(held=True)
    s.columns["t_in"][:] = np.nan
    f = heated_floor(s)
    assert not f.held and "t_in" in f.reason


def test_a_flat_outside_is_undecided():
    s = series(held=True)
    s.columns["t_out"][:] = 5.0
    f = heated_floor(s)
    assert not f.held and f.spread == 0.0 and f.ratio is None


def test_the_hint_names_the_heated_model_once():
    from gateway.cli.diagnose import live_model_hint

    floor = heated_floor(series(held=True))
    base = [{"structure": "base", "kept": True}]
    vent = [*base, {"structure": "vent controller", "kept": True}]
    hint = live_model_hint("prototype", base, floor)
    assert hint is not None and "--model prototype+vent_control+heating" in hint
    assert "vent controller" not in hint
    both = live_model_hint("prototype", vent, floor)
    assert both is not None and "--model prototype+vent_control+heating" in both
    assert "carries the vent controller" in both and "--model prototype+vent_control " not in both
    assert live_model_hint("prototype+vent_control", base, floor) == hint
    assert live_model_hint("prototype+vent_control+heating", vent, floor) is None
    following = heated_floor(series(held=False))
    assert live_model_hint("prototype", base, following) is None
    assert "--model prototype+vent_control " in live_model_hint("prototype", vent, following)


@pytest.mark.parametrize("held", [True, False])
def test_cli_json_and_text_carry_the_hint(tmp_path, capsys, monkeypatch, held):
    """``gateway diagnose`` on a kit CSV: the detector reads the data the command loaded. The
    diagnosis itself is stubbed (its base kept nothing but the base): the test is about the
    command's plumbing, not the calibration."""
    import gateway.diagnose
    from gateway.cli import main
    from gateway.kitcsv import write_kit_csv

    def stub(series, gh, model, split, seed, progress):
        return SimpleNamespace(time=series.time, split_index=len(series) // 2,
                               structure=[{"structure": "base", "kept": True}])

    monkeypatch.setattr(gateway.diagnose, "diagnose", stub)
    monkeypatch.setattr(gateway.diagnose, "to_json", lambda d: {"base_structure": d.structure})
    monkeypatch.setattr("gateway.cli.diagnose._print_human", lambda d: None)
    time, cols = kit_columns(12.0, held)
    write_kit_csv(tmp_path / "kit.csv", time, cols)
    (tmp_path / "gh.toml").write_text('name = "h"\n[geometry]\nfloor_area = 877.0\nvolume = '
                                      '3069.5\n[site]\nlatitude = 52.03\nlongitude = 4.53\n')
    argv = ["diagnose", "--data", str(tmp_path / "kit.csv"), "--greenhouse",
            str(tmp_path / "gh.toml"), "--model", "prototype", "--step", "300"]
    reported = []  # --report's hint: what write_report is given (its figures need a real run)

    def report(d, out, source, notes=(), hint=None):
        reported.append(hint)
        return tmp_path / "rep" / "report.md"

    monkeypatch.setattr("gateway.diagnose.report.write_report", report)
    assert main([*argv, "--json", "--report", str(tmp_path / "rep")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["heated_floor"]["held"] is held
    if held:
        assert "--model prototype+vent_control+heating" in out["hint"]
        assert out["hint_model"] == "prototype+vent_control+heating"
    else:
        assert out["hint"] is None and out["hint_model"] is None
    assert reported == [out["hint"]]
    assert main(argv) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("hint: ")]
    assert len(lines) == (1 if held else 0)

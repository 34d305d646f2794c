"""Notes on unusual but valid data are complete and machine-readable (docs/data-format.md,
"Notes"): the same notes in calibrate's, replay's and diagnose's text, in their JSON
(``notes``: code, level, message) and in diagnose's report.md, and none on ordinary data."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gateway.cli import main
from gateway.kitcsv import write_kit_csv

LAT, LON = 52.0, 4.5
"""The site of the test greenhouse: solar noon near 11:45 UTC."""
FAST = {"calibrate": ["--iterations", "2", "--population", "4"],
        "replay": ["--set", "t_in.iterations=2", "--set", "t_in.bats=4"], "diagnose": []}
"""The quickest swarms: these tests check what is said about the data, not the fits."""


def _greenhouse(folder: Path) -> Path:
    gh = folder / "gh.toml"
    gh.write_text('name = "g"\n\n[geometry]\nfloor_area = 20.0\nvolume = 50.0\n\n'
                  f"[site]\nlatitude = {LAT}\nlongitude = {LON}\n", encoding="utf-8")
    return gh


def _kit(path: Path, days: float, noon_utc_h: float = 11.75, drop: tuple[str, ...] = (),
         hole: bool = False, extra: dict[str, float] | None = None) -> Path:
    """``days`` of 5-minute rows from midnight UTC: radiation peaking at ``noon_utc_h`` (UTC),
    the inside following it; without the columns ``drop``; ``hole``: 2 h without t_in in the
    middle; ``extra``: constant columns."""
    t = np.datetime64("2020-03-27T00:00:00", "s") + np.arange(int(days * 288)) * np.timedelta64(300, "s")
    n = len(t)
    hours = (t - t[0]).astype(float) / 3600.0
    sun = np.maximum(np.cos(2 * np.pi * (hours - noon_utc_h) / 24.0), 0.0) ** 1.5
    rng = np.random.default_rng(5)
    cols = {"t_out": np.round(10.0 + 5.0 * np.sin(2 * np.pi * (hours - 9.0) / 24.0), 2),
            "rh_in": np.full(n, 65.0), "rh_out": np.round(70.0 - 10.0 * sun, 1),
            "i_glob": np.round(700.0 * sun, 1), "wind": np.full(n, 2.0)}
    cols["t_in"] = np.round(cols["t_out"] + 3.0 + 10.0 * np.roll(sun, 6)
                            + rng.normal(0.0, 0.1, n), 2)
    if hole:
        cols["t_in"][n // 2: n // 2 + 24] = np.nan
    for name, value in (extra or {}).items():
        cols[name] = np.full(n, value)
    return write_kit_csv(path, t, {k: v for k, v in cols.items() if k not in drop})


def _run(capsys, command: str, data: Path, greenhouse: str, *more: str) -> tuple[str, str]:
    model = "almeria" if greenhouse == "almeria-palmerillas" else "prototype"
    code = main([command, "--data", str(data), "--greenhouse", greenhouse, "--model", model,
                 "--step", "300", *FAST[command], *more])
    out, err = capsys.readouterr()
    assert code == 0 and "Traceback" not in err, err
    return out, err


def _codes(out: str) -> list[str]:
    return [n["code"] for n in json.loads(out)["notes"]]


UNUSUAL = {"data_gaps", "site_time_mismatch", "no_rh_out"}
"""What the unusual record earns in every command: a hole in t_in, daylight at the site's night
(noon at 0 UTC, a longitude of the wrong sign), no outside humidity."""


@pytest.mark.parametrize("command", ["calibrate", "replay"])
def test_each_note_is_in_the_text_and_the_json(capsys, tmp_path, command):
    gh = str(_greenhouse(tmp_path))
    data = _kit(tmp_path / "odd.csv", 0.5, noon_utc_h=0.0, drop=("rh_out", "rh_in"), hole=True)
    out, err = _run(capsys, command, data, gh, "--json")
    notes = json.loads(out)["notes"]
    assert {n["code"] for n in notes} == UNUSUAL and len(notes) == len(UNUSUAL)
    for n in notes:
        assert n["message"] in err and set(n) == {"code", "level", "message"}
        assert n["level"] == ("warning" if n["code"] == "site_time_mismatch" else "note")
    sky = next(n["message"] for n in notes if n["code"] == "no_rh_out")
    assert f"{data}: no column rh_out" in sky and "outside air temperature alone" in sky
    out, _ = _run(capsys, command, data, gh)
    for n in notes:
        assert f"{n['level']}: {n['message']} [{n['code']}]" in out


def test_each_diagnose_note_is_in_the_text_the_json_and_the_report(capsys, tmp_path):
    gh = str(_greenhouse(tmp_path))
    data = _kit(tmp_path / "odd.csv", 1.5, noon_utc_h=0.0, drop=("rh_out", "rh_in"), hole=True)
    out, err = _run(capsys, "diagnose", data, gh, "--json", "--report", str(tmp_path / "rep"))
    notes = json.loads(out)["notes"]
    assert set(_codes(out)) == UNUSUAL | {"no_rh_in", "short_heldout"} and len(notes) == 5
    humidity = [n["message"] for n in notes if n["code"] in ("no_rh_out", "no_rh_in")]
    assert all("humidity evidence" in m for m in humidity)
    report = (tmp_path / "rep" / "report.md").read_text(encoding="utf-8")
    assert "## Notes" in report and report.index("## Notes") < report.index("## Findings")
    for n in notes:
        assert f"`{n['code']}`: {n['message']}" in report
    assert "**warning** `site_time_mismatch`" in report
    # the text output's block is text_block's, as calibrate's and replay's (tested above)
    assert all(n["message"] in err for n in notes)


def test_the_csv_readers_notices_are_notes_too(capsys, tmp_path):
    data = _kit(tmp_path / "extra.csv", 0.5)
    lines = data.read_text().splitlines()
    lines = [lines[0] + ",co2_ppm"] + [row + ",400" for row in lines[1:]]
    data.write_text("\n".join([*lines, lines[-1]]) + "\n")  # and the last row sent twice
    out, err = _run(capsys, "calibrate", data, str(_greenhouse(tmp_path)), "--json")
    notes = json.loads(out)["notes"]
    assert [n["code"] for n in notes] == ["csv_reader", "csv_reader"]
    assert "ignoring unknown column(s) co2_ppm" in notes[0]["message"]
    assert all(f"note: {n['message']}" not in err for n in notes)  # the reader logs them itself


def test_the_csv_readers_notices_read_as_notes_on_a_piped_stderr(tmp_path):
    """The real command, stderr on a pipe: the reader's notices (logged by gateway/kitcsv.py)
    are ``note: …`` lines as the other notes, once each, not ``WARNING gateway.kitcsv: …``;
    and python -m training.vsensor says them the same way."""
    data = _kit(tmp_path / "extra.csv", 0.5)
    lines = data.read_text().splitlines()
    data.write_text("\n".join([lines[0] + ",co2_ppm"] + [row + ",400" for row in lines[1:]]) + "\n")
    r = subprocess.run([sys.executable, "-m", "gateway", "calibrate", "--data", str(data),
                        "--greenhouse", str(_greenhouse(tmp_path)), "--model", "prototype",
                        "--step", "300", *FAST["calibrate"], "-q"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    said = f"note: {data}: ignoring unknown column(s) co2_ppm"
    assert r.stderr.splitlines().count(said) == 1 and "WARNING" not in r.stderr, r.stderr
    assert f"{said} [csv_reader]" in r.stdout.splitlines()  # the report's closing block
    r = subprocess.run([sys.executable, "-m", "training.vsensor", "reference", "--data", str(data),
                        "--greenhouse", "biskra-prototype", "--model", "prototype"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.splitlines()[0] == said, r.stderr  # then: no vents


@pytest.mark.parametrize("command", ["calibrate", "replay"])
def test_ordinary_data_gives_no_note(capsys, tmp_path, command):
    gh = str(_greenhouse(tmp_path))
    data = _kit(tmp_path / "fine.csv", 0.5)
    out, err = _run(capsys, command, data, gh, "--json")
    assert json.loads(out)["notes"] == [] and "note:" not in err and "warning:" not in err
    out, err = _run(capsys, command, data, gh)
    assert "note:" not in out + err and "warning:" not in out + err


ALMERIA = {"no_vent_opening", "no_lai", "no_i_in"}
"""What the Almería model reads when there and takes a stand-in for when not."""


def test_the_almeria_models_stand_ins_are_named(capsys, tmp_path):
    bare = _kit(tmp_path / "bare.csv", 1.0, noon_utc_h=12.2, extra={"t_soil": 18.0})
    out, _ = _run(capsys, "calibrate", bare, "almeria-palmerillas", "--json")
    notes = json.loads(out)["notes"]
    assert set(_codes(out)) == ALMERIA
    vents = [n["message"] for n in notes if n["code"] == "no_vent_opening"]
    assert len(vents) == 2 and any("no column vent_roof" in m and "5 in the greenhouse" in m
                                   for m in vents)
    assert any("lai, 2 m2 m-2" in n["message"] for n in notes if n["code"] == "no_lai")
    full = _kit(tmp_path / "full.csv", 1.0, noon_utc_h=12.2,
                extra={"t_soil": 18.0, "vent_roof": 10.0, "vent_side": 0.0, "lai": 2.0,
                       "i_in": 100.0})
    out, _ = _run(capsys, "calibrate", full, "almeria-palmerillas", "--json")
    assert _codes(out) == []


def test_partly_missing_optional_columns_are_counted(tmp_path):
    from gateway.cli.column_notes import column_notes
    from gateway.greenhouse import load_greenhouse
    from gateway.model import build_model
    from gateway.series import load_series

    cols = {"t_soil": 18.0, "vent_roof": 10.0, "vent_side": 5.0}
    path = _kit(tmp_path / "holes.csv", 1.0, extra=cols)
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    for i in range(10, 40):  # 30 rows without rh_out and the roof vent
        cells = lines[i].split(",")
        cells[header.index("rh_out")] = cells[header.index("vent_roof")] = ""
        lines[i] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    gh = load_greenhouse("almeria-palmerillas")
    model = build_model("almeria", gh)
    series = load_series(str(path), step=300.0, required=model.requires)
    got = dict(column_notes(series, gh, model, str(path), "replay"))
    assert set(got) == {"rh_out_gaps", "vent_opening_gaps", "no_lai", "no_i_in"}
    assert "rh_out is empty on 30 of 288 rows" in got["rh_out_gaps"]
    assert "vent_roof is empty on 30 of 288 rows" in got["vent_opening_gaps"]
    assert "roof vents" in got["vent_opening_gaps"]
    assert "rh_out_gaps" not in dict(column_notes(series, gh, model, str(path), "calibrate"))


REQUIRED = [("prototype", c) for c in ("t_in", "t_out", "i_glob", "wind")] + \
    [("almeria", c) for c in ("rh_in", "t_soil")]


@pytest.mark.parametrize("command", ["calibrate", "replay", "diagnose"])
@pytest.mark.parametrize(("model", "column"), REQUIRED)
def test_a_missing_required_column_names_the_file_and_the_column(capsys, tmp_path, command,
                                                                  model, column):
    extra = {"t_soil": 18.0} if column != "t_soil" else {}
    data = _kit(tmp_path / "lacks.csv", 1.0, drop=(column,), extra=extra)
    greenhouse = "almeria-palmerillas" if model == "almeria" else "biskra-prototype"
    assert main([command, "--data", str(data), "--greenhouse", greenhouse, "--model", model,
                 "--step", "300"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    assert f"error: {data}:1: missing required column(s) {column}" in err.splitlines()[-1]
    empty = _kit(tmp_path / "empty.csv", 1.0, extra={**extra, column: np.nan})
    assert main([command, "--data", str(empty), "--greenhouse", greenhouse, "--model", model,
                 "--step", "300"]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"error: {empty}: column(s) {column} hold no value" in line


def _vsensor(capsys, tmp_path: Path, toml: str, *more: str) -> tuple[dict, str, str]:
    """``vsensor --json`` (the shipped almeria sensor, no baselines) on 20 minutes of kit rows
    with an unknown column, for a greenhouse described by ``toml``."""
    gh = tmp_path / "gh.toml"
    gh.write_text(toml, encoding="utf-8")
    rows = ["time,t_in,rh_in,t_out,rh_out,i_glob,wind,t_soil,vent_roof,bogus"]
    rows += [f"2020-03-27T10:{k:02d}:00Z,20.0,60.0,15.0,55.0,400.0,1.5,18.0,10.0,1"
             for k in range(20)]
    data = tmp_path / "v.csv"
    data.write_text("\n".join(rows) + "\n", encoding="utf-8")
    code = main(["vsensor", "--data", str(data), "--greenhouse", str(gh), "--model-kind",
                 "almeria", "--no-baselines", *more])
    out, err = capsys.readouterr()
    assert code == 0 and "Traceback" not in err, err
    return (json.loads(out) if "--json" in more else {}), out, err


def test_vsensor_notes_are_records_in_its_json_and_its_text(capsys, tmp_path):
    """vsensor's notes are the other commands' (gateway/cli/notes.py): ``{code, level,
    message}`` in ``--json``, ``level: message [code]`` after the text report, each on stderr;
    the CSV reader's notice and the missing site among them, not only on stderr."""
    from gateway.greenhouse import PRESET_DIR

    text = (PRESET_DIR / "almeria-palmerillas.toml").read_text()
    no_site = text[: text.index("[site]")] + text[text.index("[geometry]"):]
    rep, _, err = _vsensor(capsys, tmp_path, no_site, "--json")
    notes = rep["notes"]
    # the almeria model's stand-ins too (no lai, no i_in); its replay leaves the vents out by
    # design, so a missing vent_side is not a note
    assert [n["code"] for n in notes] == ["csv_reader", "no_site", "no_lai", "no_i_in"], notes
    assert all(set(n) == {"code", "level", "message"} and n["level"] == "note" for n in notes)
    assert "bogus" in notes[0]["message"] and all(n["message"] in err for n in notes[1:])
    other = no_site.replace("roof_count = 5", "roof_count = 2")  # another house's vents
    rep, _, err = _vsensor(capsys, tmp_path, other, "--json", "--site", "36.79,-2.72")
    assert [n["code"] for n in rep["notes"]] == ["csv_reader", "no_lai", "no_i_in",
                                                 "other_greenhouse"]
    warn = rep["notes"][-1]
    assert warn["level"] == "warning" and "roof_vent_area_m2" in warn["message"]
    assert warn["message"] in err and rep["flagged"] == rep["steps"]
    _, out, _ = _vsensor(capsys, tmp_path, other, "--site", "36.79,-2.72")
    assert f"warning: {warn['message']} [other_greenhouse]" in out


def test_vsensor_runs_the_input_checks_the_other_commands_run(capsys, tmp_path):
    """vsensor said only the CSV reader's notices and a missing site; the shared checks
    (gateway/cli/notes.py ``input_notes``) now run on its data too: a hole in a column it
    needs, daylight in the site's night (a warning), in its JSON, its text and on stderr."""
    data = _kit(tmp_path / "odd.csv", 0.5, noon_utc_h=0.0, hole=True)
    argv = ["vsensor", "--data", str(data), "--greenhouse", "almeria-palmerillas",
            "--model-kind", "prototype", "--no-baselines"]
    assert main([*argv, "--json"]) == 0
    out, err = capsys.readouterr()
    notes = json.loads(out)["notes"]
    assert [(n["code"], n["level"]) for n in notes] == [("data_gaps", "note"),
                                                       ("site_time_mismatch", "warning")]
    gaps = notes[0]["message"]
    assert gaps.startswith(f"{data}: ") and "lack a value the model or the sensor needs" in gaps
    assert all(f"{n['level']}: {n['message']}" in err for n in notes)
    assert main(argv) == 0
    out, _ = capsys.readouterr()
    assert out.endswith("".join(f"{n['level']}: {n['message']} [{n['code']}]\n" for n in notes))

"""A new user's mistakes with data and models on the command lines (kit CSVs, spans, sites,
sensors, simulator settings): each is one line naming the file, line, key or option and what
was wrong, exit status 2, never a traceback."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gateway.cli import main
from gateway.kitcsv import write_kit_csv
from tests.cli_mistakes_common import PROTO, kit_csv, one_error_line


def test_the_clear_sky_outlook_without_a_site_says_how_to_give_one(capsys, tmp_path):
    gh = tmp_path / "nosite.toml"
    gh.write_text('name = "x"\n[geometry]\nfloor_area = 0.68\nvolume = 0.76\n')
    data = kit_csv(tmp_path)
    assert main(["replay", "--data", str(data), "--greenhouse", str(gh), "--model", "prototype",
                 "--outlook", "clear-sky-trend"]) == 2
    line = one_error_line(capsys)
    assert str(gh) in line and "[site]" in line and "--site LAT,LON" in line


def test_vsensor_without_a_shipped_sensor_for_the_kind_is_one_line(capsys, tmp_path, monkeypatch):
    from gateway.vsensor import models

    monkeypatch.setattr(models, "MODEL_DIR", tmp_path)  # a wheel without the prototype's sensor
    data = kit_csv(tmp_path)
    assert main(["vsensor", "--data", str(data), "--greenhouse", "biskra-prototype",
                 "--model-kind", "prototype"]) == 2
    line = one_error_line(capsys)
    assert "'prototype' model" in line and "--sensor MODEL.onnx" in line


def test_vsensor_data_errors_come_before_the_sensor_is_looked_for(capsys, tmp_path):
    missing = tmp_path / "none.csv"
    assert main(["vsensor", "--data", str(missing), "--greenhouse", "biskra-prototype",
                 "--model-kind", "prototype"]) == 2
    assert f"{missing}: cannot open" in one_error_line(capsys)


def test_vsensor_model_kind_given_as_the_sensor_file_is_named(capsys, tmp_path):
    data = kit_csv(tmp_path)
    assert main(["vsensor", "--data", str(data), "--greenhouse", "almeria-palmerillas",
                 "--model-kind", "almeria", "--model", "almeria"]) == 2
    line = one_error_line(capsys)
    assert "--model almeria: that is a model kind" in line and "--model-kind almeria" in line


def test_vsensor_missing_sensor_file_is_named(capsys, tmp_path):
    data, onnx = kit_csv(tmp_path), tmp_path / "mine.onnx"
    assert main(["vsensor", "--data", str(data), "--greenhouse", "biskra-prototype",
                 "--model-kind", "prototype", "--sensor", str(onnx)]) == 2
    assert f"--sensor {onnx}: no such file" in one_error_line(capsys)


def _vsensor_on(data, kind: str, greenhouse: str, *more: str) -> int:
    return main(["vsensor", "--data", str(data), "--greenhouse", greenhouse, "--model-kind", kind,
                 "--no-baselines", *more])


@pytest.mark.parametrize(("kind", "greenhouse", "drop", "said"), [
    ("prototype", "biskra-prototype", ("rh_in",),
     "no column rh_in (the sensor's inputs drh_in_out, vpd_in)"),
    ("prototype", "biskra-prototype", ("rh_in", "rh_out"),
     "no column rh_in (the sensor's inputs drh_in_out, vpd_in); no column rh_out (the sensor's "
     "input drh_in_out)"),
    ("almeria", "almeria-palmerillas", ("rh_out",),
     "no column rh_out (the sensor's input drh_in_out)")])
def test_vsensor_without_a_column_its_sensor_reads_names_the_file_column_and_sensor(
        capsys, tmp_path, kind, greenhouse, drop, said):
    """A CSV without a column the sensor makes an input from ran with that input NaN on every
    minute (all flagged); it is now one line naming the file, the column(s), the inputs made
    from them and the sensor."""
    from gateway.vsensor.models import shipped_model

    full = kit_csv(tmp_path, name="full.csv")
    lines = full.read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if h not in drop]
    extra = ",t_soil" if kind == "almeria" else ""
    rows = [",".join(header[i] for i in keep) + extra]
    rows += [",".join(r.split(",")[i] for i in keep) + (",18.0" if extra else "")
             for r in lines[1:]]
    data = tmp_path / "lacks.csv"
    data.write_text("\n".join(rows) + "\n")
    assert _vsensor_on(data, kind, greenhouse) == 2
    assert one_error_line(capsys) == (
        f"error: {data}: {said}: the virtual sensor {shipped_model(kind)} ({kind} kind) cannot "
        "run without them; give the column(s) with values (cells left empty here and there only "
        "flag their minutes)")


def test_vsensor_with_a_column_empty_everywhere_or_here_and_there(capsys, tmp_path):
    """A column with no value at all is as good as absent (refused, named); one with some
    empty cells runs as before, those minutes flagged for the missing input."""
    full = kit_csv(tmp_path, name="full.csv")
    lines = full.read_text().splitlines()
    col = lines[0].split(",").index("rh_in")

    def blank(name: str, rows: set[int]) -> object:
        out = [lines[0]]
        for k, r in enumerate(lines[1:]):
            cells = r.split(",")
            cells[col] = "" if k in rows else cells[col]
            out.append(",".join(cells))
        path = tmp_path / name
        path.write_text("\n".join(out) + "\n")
        return path

    empty = blank("empty.csv", set(range(len(lines))))
    assert _vsensor_on(empty, "prototype", "biskra-prototype") == 2
    line = one_error_line(capsys)
    assert line.startswith(f"error: {empty}: column rh_in is empty (the sensor's inputs "
                           "drh_in_out, vpd_in): the virtual sensor ")
    holes = blank("holes.csv", set(range(10, 20)))
    assert _vsensor_on(holes, "prototype", "biskra-prototype", "--json") == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["missing_by_input"]["drh_in_out"] > 0 and rep["flagged"] >= rep["missing"] > 0
    assert "data_gaps" in [n["code"] for n in rep["notes"]]


def test_a_typo_in_the_header_names_the_unknown_column_and_the_kit_name(capsys, tmp_path):
    data = kit_csv(tmp_path)
    lines = data.read_text().splitlines()
    lines[0] = lines[0].replace("t_in", "T_in").replace("wind", "windspeed")
    data.write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    line = one_error_line(capsys)
    assert f"{data}:1: missing required column(s) t_in, wind" in line
    assert "'T_in' (did you mean 't_in'?)" in line and "'windspeed' (did you mean 'wind'?)" in line


def test_a_byte_that_is_not_utf8_far_into_the_file_names_its_line(capsys, tmp_path):
    data = kit_csv(tmp_path, rows=600)  # ~30 kB: past the first block the reader decodes
    raw = data.read_bytes().splitlines(keepends=True)
    raw[499] = raw[499].replace(b"60,", b"6\xe90,", 1)  # Latin-1 'é' on line 500
    data.write_bytes(b"".join(raw))
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    line = one_error_line(capsys)
    assert f"{data}:500: not UTF-8 text" in line


def test_utf16_is_named(capsys, tmp_path):
    data = kit_csv(tmp_path)
    data.write_bytes(data.read_text().encode("utf-16"))
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    assert f"{data}: UTF-16 text" in one_error_line(capsys)


@pytest.mark.parametrize("span,message", [
    ("2020-03-27", "expected START/END"),
    ("yesterday/2020-03-28", "START 'yesterday' is not an ISO 8601 date or time, e.g."),
    ("2020-03-27/2020-13-01", "END '2020-13-01' is not an ISO 8601 date or time (month"),
    ("2020-03-27T10:10/2020-03-27T10:02", "END is not after START"),
])
def test_calibrate_on_mistakes_say_which_end_is_wrong(capsys, tmp_path, span, message):
    data = kit_csv(tmp_path)
    assert main(["calibrate", "--data", str(data), *PROTO, "--calibrate-on", span]) == 2
    line = one_error_line(capsys)
    assert f"--calibrate-on {span!r}: {message}" in line and "unpack" not in line


@pytest.mark.parametrize("option,value", [("--step", "0"), ("--days", "-1"), ("--days", "inf")])
def test_simulate_refuses_a_step_or_length_that_is_not_positive(capsys, tmp_path, option, value):
    from training.__main__ import main as training_main

    with pytest.raises(SystemExit) as exc:
        training_main(["simulate", "--out", str(tmp_path / "s.csv"), option, value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: must be a positive number, got '{value}'" in err
    assert "Traceback" not in err


def test_training_vsensor_mistakes_are_one_line_exit_2(capsys, tmp_path):
    from training.vsensor.cli import main as vsensor_main

    common = ["--greenhouse", "almeria-palmerillas", "--model", "almeria", "--cache",
              str(tmp_path / "cache")]
    missing = tmp_path / "none.csv"
    assert vsensor_main(["dataset", "--data", str(missing), *common]) == 2
    line = one_error_line(capsys)
    assert f"error: {missing}: No such file" in line and "Errno" not in line
    assert vsensor_main(["dataset", "--data", str(missing), *common, "--set", "t_in.x"]) == 2
    assert "--set 't_in.x': expected OUTPUT.KEY=NUMBER" in one_error_line(capsys)
    assert vsensor_main(["corpus", "--out", str(tmp_path / "c"), "--only", "no-such-run"]) == 2
    assert "--only: no run named no-such-run (runs: " in one_error_line(capsys)
    assert not (tmp_path / "c").exists()


def test_a_gap_in_the_data_is_said_once_with_its_length_and_start(capsys, tmp_path):
    data = kit_csv(tmp_path)
    lines = data.read_text().splitlines()
    data.write_text("\n".join(lines[:10] + lines[20:]) + "\n")  # 10:09 to 10:18 never sent
    assert main(["replay", "--data", str(data), *PROTO, "--json"]) == 0
    err = capsys.readouterr().err
    assert (f"note: {data}: 10 of 30 rows on the 60 s grid lack a value the model needs, in 1 "
            f"hole(s), the longest 10 min from 2020-03-27T10:09:00Z") in err
    assert main(["replay", "--data", str(kit_csv(tmp_path, name="whole.csv")), *PROTO,
                 "--json"]) == 0
    assert "lack a value" not in capsys.readouterr().err  # whole data: no note


def test_simulate_says_when_an_effect_starts_after_the_run(capsys, tmp_path):
    from training.__main__ import main as training_main

    late = "heater@2009-12-01:power=30"  # the run covers 2009-11-01, a quarter of an hour
    assert training_main(["simulate", "--out", str(tmp_path / "s.csv"), "--days", "0.01",
                          "--effect", "none", "--effect", late]) == 0
    err = capsys.readouterr().err
    assert f"note: --effect {late}: starts at 2009-12-01T00:00:00Z, after the simulated span" in err
    assert training_main(["simulate", "--out", str(tmp_path / "t.csv"), "--days", "0.01",
                          "--effect", "heater:power=30"]) == 0
    assert "note" not in capsys.readouterr().err


def test_vsensor_says_what_a_greenhouse_without_site_means_and_takes_site(capsys, tmp_path):
    from gateway.greenhouse import PRESET_DIR

    text = (PRESET_DIR / "almeria-palmerillas.toml").read_text()
    start, end = text.index("[site]"), text.index("[geometry]")
    gh = tmp_path / "nosite.toml"
    gh.write_text(text[:start] + text[end:])
    t = np.datetime64("2020-03-27T10:00:00", "s") + np.arange(20) * np.timedelta64(60, "s")
    cols = {c: np.full(20, v) for c, v in (("t_in", 20.0), ("rh_in", 60.0), ("t_out", 15.0),
                                            ("rh_out", 55.0), ("i_glob", 400.0), ("wind", 1.5),
                                            ("i_in", 250.0), ("t_soil", 18.0), ("lai", 2.0))}
    data = write_kit_csv(tmp_path / "a.csv", t, cols)
    common = ["vsensor", "--data", str(data), "--greenhouse", str(gh), "--model-kind", "almeria",
              "--no-baselines", "--json"]
    assert main(common) == 0
    assert f"note: {gh} gives no [site] and no --site was given" in capsys.readouterr().err
    assert main([*common, "--site", "36.79,-2.72"]) == 0
    assert "no [site]" not in capsys.readouterr().err


def test_simulate_help_names_the_gateway_presets_that_read_its_csv(capsys):
    from gateway.greenhouse import list_presets
    from gateway.model import MODEL_NAMES
    from training.__main__ import main as training_main

    with pytest.raises(SystemExit):
        training_main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split()).replace("- ", "-")
    for plant, preset in (("almeria", "almeria-palmerillas"), ("prototype", "biskra-prototype")):
        assert preset in list_presets() and plant in MODEL_NAMES
        assert preset in text


def test_replay_says_when_a_starting_parameter_is_outside_its_hard_box(capsys, tmp_path):
    from gateway.greenhouse import load_greenhouse
    from gateway.model import build_model

    model = build_model("prototype", load_greenhouse("biskra-prototype"))
    lo, hi = model.bounds(load_greenhouse("biskra-prototype"))
    params = tmp_path / "p.toml"
    values = {n: float(0.5 * (a + b)) for n, a, b in zip(model.names, lo, hi, strict=True)}
    values["c_solar"] = 1e9  # a hand edit: calibrate never writes this
    params.write_text('model = "prototype"\n[params]\n'
                      + "".join(f"{n} = {v!r}\n" for n, v in values.items()))
    data = kit_csv(tmp_path)
    assert main(["replay", "--data", str(data), *PROTO, "--params", str(params), "--json"]) == 0
    err = capsys.readouterr().err
    j = model.names.index("c_solar")
    assert (f"note: {params}: params.c_solar = 1e+09 is outside its hard box "
            f"[{lo[j]:g}, {hi[j]:g}]") in err and f"use {hi[j]:g}" in err
    assert err.count("outside its hard box") == 1  # the others are inside


@pytest.mark.parametrize(("floor_area", "volume", "height"), [
    (6800.0, 0.76, "0.000112 m"),  # the floor area in cm2
    (0.68, 760.0, "1.12e+03 m"),  # the volume in litres
])
def test_a_floor_area_and_volume_in_units_that_disagree_are_refused(capsys, tmp_path, floor_area,
                                                                    volume, height):
    gh = tmp_path / "mine.toml"  # each key alone is inside its range
    gh.write_text(f'name = "mine"\n[geometry]\nfloor_area = {floor_area}\nvolume = {volume}\n')
    data = kit_csv(tmp_path)
    assert main(["calibrate", "--data", str(data), "--greenhouse", str(gh), "--model",
                 "prototype", "--iterations", "1", "--population", "2"]) == 2
    line = one_error_line(capsys)
    assert line.startswith(f"error: {gh}: 'geometry.volume' / 'geometry.floor_area' = {height}")
    assert "mean height is impossible" in line and "floor_area in m2, volume in m3" in line


def test_vsensor_says_what_it_clamped_in_words_not_as_its_clamp_inputs_option(capsys, tmp_path):
    """'300 clamped' read as if the inputs had been clamped though --clamp-inputs was off: the
    count is of flows held to [0, the physical maximum], and says so; the inputs fed at their
    bound are counted only with the option."""
    data = kit_csv(tmp_path)
    assert _vsensor_on(data, "prototype", "biskra-prototype", "--json") == 0
    counts = json.loads(capsys.readouterr().out)
    assert counts["inputs_clamped"] == 0  # the kit rows are inside the training ranges
    for more in ((), ("--clamp-inputs",)):
        assert _vsensor_on(data, "prototype", "biskra-prototype", *more) == 0
        head = capsys.readouterr().out.splitlines()[0]
        assert head.endswith(f", {counts['clamped']} with the flow held to [0, its physical "
                             "maximum]")  # nothing about inputs: none was fed at its bound
    rows = data.read_text().splitlines()  # a storm: wind far above the training range
    storm = tmp_path / "storm.csv"
    storm.write_text("\n".join([rows[0], *(r.rsplit(",", 1)[0] + ",35" for r in rows[1:])]) + "\n")
    assert rows[0].endswith(",wind")
    assert _vsensor_on(storm, "prototype", "biskra-prototype", "--clamp-inputs") == 0
    head = capsys.readouterr().out.splitlines()[0]
    assert head.endswith(f", {len(rows) - 1} with inputs fed at their bound (--clamp-inputs)")


@pytest.mark.parametrize(("cell", "hint"), [
    ("NA", " (a missing value is an empty cell)"),  # R, pandas
    ("#N/A", " (a missing value is an empty cell)"),  # a spreadsheet
    ("1.5 m/s", ""),  # not a missing mark: no hint that would mislead
])
def test_a_missing_value_written_as_a_word_says_to_leave_the_cell_empty(capsys, tmp_path, cell,
                                                                         hint):
    data = kit_csv(tmp_path)
    lines = data.read_text().splitlines()
    assert lines[0].endswith(",wind")
    lines[7] = lines[7].rsplit(",", 1)[0] + f",{cell}"  # line 8 of the file
    data.write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    assert one_error_line(capsys) == f"error: {data}:8: column wind: not a number: {cell!r}{hint}"


@pytest.mark.parametrize(("header", "found"), [
    ("Time,T_in,rh_in,t_out,rh_out,i_glob,wind",
     "found 'Time' (column names are lower case: time, t_in, ...)"),
    ("time;t_in;rh_in", "found 'time;t_in;rh_in' (the separator must be a comma, not ';')"),
    ("", "found an empty line"),
])
def test_a_header_without_time_first_says_what_it_found_as_text(capsys, tmp_path, header, found):
    data = kit_csv(tmp_path)  # was: found ['Time'], a Python list, and no word on the case
    data.write_text(header + "\n" + data.read_text().split("\n", 1)[1])
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    assert one_error_line(capsys) == f"error: {data}:1: the first column must be 'time', {found}"


def test_a_bad_cell_says_how_many_more_follow_and_where_the_next_is(capsys, tmp_path):
    """A humidity sensor reading 100.4 % in fog does so for hours: one line at a time, a user
    would fix the file line by line without knowing how many are left."""
    data = kit_csv(tmp_path, rows=40)
    lines = data.read_text().splitlines()
    col = lines[0].split(",").index("rh_in")
    for k in (5, 9, 17, 30):  # lines 6, 10, 18, 31 of the file
        cells = lines[k].split(",")
        cells[col] = "100.4"
        lines[k] = ",".join(cells)
    data.write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    assert one_error_line(capsys) == (
        f"error: {data}:6: column rh_in: 100.4 % outside the physical range [0, 100] (relative "
        "humidity cannot exceed 100 %) (and 3 more bad cell(s) after it, the next on line 10)")
    lines[20] = lines[11]  # a row out of order after the first bad cell: the bad cell is first
    data.write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    assert one_error_line(capsys).startswith(f"error: {data}:6: column rh_in: 100.4 %")


@pytest.mark.parametrize(("setting", "said"), [
    ("t_in.window=1e9", "'online.t_in.window' = 1000000000 is impossible (expected 1..10000)"),
    ("t_in.bats=1", "'online.t_in.bats' = 1 is impossible (expected 2..10000)"),  # was "must be
    ("t_in.prior=nan", "'online.t_in.prior' = nan is impossible (expected 0..1e+06)"),  # positive"
])
def test_replay_set_takes_the_bounds_of_a_greenhouse_files_online_table(capsys, tmp_path, setting,
                                                                        said):
    """'--set t_in.window=1e9' bypassed the bounds [online.t_in] has in a greenhouse file and
    died allocating 30 GB (a traceback); '--set t_in.bats=1' said 'must be positive, got 1'."""
    missing = tmp_path / "not-made-yet.csv"  # said before the data is read
    assert main(["replay", "--data", str(missing), *PROTO, "--set", setting]) == 2
    assert one_error_line(capsys) == f"error: --set {setting!r}: {said}"


@pytest.mark.parametrize("stamp", ["27/03/2020 10:00", "1585303200"])
def test_a_time_in_another_format_is_said_in_words_not_pythons(capsys, tmp_path, stamp):
    data = kit_csv(tmp_path)  # a European spreadsheet's dates, a logger's Unix seconds
    lines = data.read_text().splitlines()
    lines[1] = stamp + "," + lines[1].split(",", 1)[1]
    data.write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "--data", str(data), *PROTO]) == 2
    assert one_error_line(capsys) == (
        f"error: {data}:2: column time: bad time {stamp!r}: not an ISO 8601 time with its UTC "
        "offset (write e.g. 2020-03-27T00:01:00Z; day/month/year and Unix seconds are not read)")

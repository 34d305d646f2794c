"""A new user's mistakes on the command lines: each is one line naming the file, line, key or
option and what was wrong, exit status 2, never a traceback; and it is said before the work
(an output that cannot be written is refused before an hour of calibration, not after)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from gateway.cli import main
from gateway.kitcsv import write_kit_csv

PROTO = ["--greenhouse", "biskra-prototype", "--model", "prototype"]


def kit_csv(folder: Path, rows: int = 30, name: str = "k.csv") -> Path:
    """A few minutes of plausible kit rows (the columns of the prototype model)."""
    t = np.datetime64("2020-03-27T10:00:00", "s") + np.arange(rows) * np.timedelta64(60, "s")
    ramp = np.arange(rows, dtype=float)
    cols = {"t_in": 20 + 0.1 * ramp, "rh_in": np.full(rows, 60.0), "t_out": 15 + 0.05 * ramp,
            "rh_out": np.full(rows, 55.0), "i_glob": 400 + ramp, "wind": np.full(rows, 1.5)}
    return write_kit_csv(folder / name, t, cols)


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    line = err.splitlines()[-1]
    assert line.startswith("error: ")
    return line


@pytest.mark.parametrize("command,option", [
    (["calibrate", "--iterations", "1", "--population", "2"], "--out"),
    (["replay"], "--out"),
    (["replay"], "--plot"),
])
def test_an_output_in_a_missing_folder_is_refused_before_the_work(capsys, tmp_path, command,
                                                                   option):
    data = kit_csv(tmp_path)
    target = tmp_path / "no-such-folder" / "out.file"
    assert main([*command, "--data", str(data), *PROTO, option, str(target)]) == 2
    line = one_error_line(capsys)
    assert f"{option} {target}" in line and "does not exist" in line
    assert not target.parent.exists()


def test_an_output_that_is_a_folder_is_named(capsys, tmp_path):
    data = kit_csv(tmp_path)
    assert main(["replay", "--data", str(data), *PROTO, "--plot", str(tmp_path)]) == 2
    assert f"--plot {tmp_path}: is a folder" in one_error_line(capsys)


def test_a_report_folder_that_is_a_file_is_refused_before_the_diagnosis(capsys, tmp_path):
    data = kit_csv(tmp_path)  # far too short to diagnose: the report is checked first
    assert main(["diagnose", "--data", str(data), *PROTO, "--report", str(data)]) == 2
    assert f"--report {data}: exists and is not a folder" in one_error_line(capsys)


def test_calibrate_writes_its_params_file_where_asked(capsys, tmp_path):
    data, out = kit_csv(tmp_path), tmp_path / "p.toml"
    assert main(["calibrate", "--data", str(data), *PROTO, "--iterations", "1", "--population",
                 "2", "--out", str(out)]) == 0
    assert "calibrated with rsba" in capsys.readouterr().out
    assert "[params]" in out.read_text()


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


@pytest.mark.parametrize("text,message", [
    ('name = "north"\n[geometry]\nvolume = 3\n', "gateway: missing (required): a [gateway] table"),
    ('[gateway]\nfarm = "f"\n', "gateway.db: missing (required)"),
    ('[gateway]\ndb = 5\n', "gateway.db: must be a path in quotes, got 5"),
    ('[gateway\ndb = "x.db"\n', "invalid TOML"),
])
def test_status_names_what_is_wrong_in_the_config(capsys, tmp_path, text, message):
    config = tmp_path / "gateway.toml"
    config.write_text(text)
    assert main(["status", "--once", "--config", str(config)]) == 2
    assert f"{config}: {message}" in one_error_line(capsys)


def test_status_on_a_config_whose_store_is_not_made_yet_says_so(capsys, tmp_path):
    config = tmp_path / "gateway.toml"
    config.write_text('[gateway]\ndb = "serra.db"\n')
    assert main(["status", "--once", "--config", str(config)]) == 2
    line = one_error_line(capsys)
    assert f"{tmp_path / 'serra.db'}: no such store (the gateway.db of {config}" in line


@pytest.mark.parametrize("db,message", [
    ("no-such-folder/serra.db", "does not exist (the gateway creates the store serra.db, not its"),
    (".", "is a folder; name the store's file"),
])
def test_run_check_refuses_a_store_it_could_not_create(capsys, tmp_path, db, message):
    assert main(["keys", "add", "7", "--keys", str(tmp_path / "keys.txt")]) == 0
    config = tmp_path / "gateway.toml"
    config.write_text(f'[gateway]\nfarm = "f1"\ndb = "{db}"\nkeys = "keys.txt"\n[[greenhouse]]\n'
                      'name = "north"\ngreenhouse = "biskra-prototype"\nmodel = "prototype"\n'
                      'inside = 7\n')
    capsys.readouterr()
    assert main(["run", "--config", str(config), "--check"]) == 2
    line = one_error_line(capsys)
    assert f"{config}: gateway.db: " in line and message in line


@pytest.mark.parametrize("option,value,message", [
    ("--retention-days", "-3", "must be at least 1, got '-3'"),  # would delete every sample
    ("--retention-days", "nan", "must be at least 1, got 'nan'"),
    ("--max-db-mb", "0", "must be at least 1, got '0'"),
    ("--batch-delay", "-1", "must be at least 0, got '-1'"),
    ("--baudrate", "9600.5", "expected a whole number, got '9600.5'"),
])
def test_ingest_refuses_numbers_outside_the_configs_bounds(capsys, tmp_path, option, value,
                                                           message):
    with pytest.raises(SystemExit) as exc:  # argparse's usage error, before anything starts
        main(["ingest", "--db", str(tmp_path / "s.db"), "--keys", str(tmp_path / "k.txt"),
              option, value])
    assert exc.value.code == 2
    assert f"argument {option}: {message}" in capsys.readouterr().err
    assert not (tmp_path / "s.db").exists()


def test_ingest_without_its_keys_file_names_it_and_how_to_make_it(capsys, tmp_path):
    keys = tmp_path / "keys.txt"
    assert main(["ingest", "--db", str(tmp_path / "s.db"), "--keys", str(keys)]) == 2
    line = one_error_line(capsys)
    assert f"{keys}: cannot read the keys file: No such file" in line
    assert "python -m gateway keys add" in line and "Errno" not in line


def test_keys_help_says_what_add_says_about_restarting(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["keys", "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "restart it afterwards" not in text and "no restart" in text
    assert main(["keys", "add", "7", "--keys", str(tmp_path / "keys.txt")]) == 0
    assert "no restart" in capsys.readouterr().err  # what add says agrees with the help


@pytest.mark.parametrize("option,value", [("--step", "0"), ("--days", "-1"), ("--days", "inf")])
def test_simulate_refuses_a_step_or_length_that_is_not_positive(capsys, tmp_path, option, value):
    from training.__main__ import main as training_main

    with pytest.raises(SystemExit) as exc:
        training_main(["simulate", "--out", str(tmp_path / "s.csv"), option, value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: must be a positive number, got '{value}'" in err
    assert "Traceback" not in err


def test_simulate_into_a_folder_is_named_before_simulating(capsys, tmp_path):
    from training.__main__ import main as training_main

    assert training_main(["simulate", "--out", str(tmp_path), "--days", "0.01"]) == 2
    assert f"--out {tmp_path}: is a folder" in one_error_line(capsys)


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


def test_subscribe_export_from_a_mistyped_store_creates_nothing(capsys, tmp_path):
    db = tmp_path / "clod.db"
    assert main(["subscribe", "--db", str(db), "--export", str(tmp_path / "csv")]) == 2
    assert f"{db}: no such cloud store" in one_error_line(capsys)
    assert not db.exists() and not (tmp_path / "csv").exists()


def test_subscribe_refuses_a_duration_that_is_not_positive(capsys, tmp_path):
    assert main(["subscribe", "--connect", "tcp/127.0.0.1:1", "--db", str(tmp_path / "c.db"),
                 "--duration", "-5"]) == 2
    assert "--duration -5: must be a positive number of seconds" in one_error_line(capsys)
    assert not (tmp_path / "c.db").exists()


@pytest.mark.parametrize("args,message", [
    (["--gateway", "bad farm!"], "gateway name 'bad farm!': use 1-63 letters"),
    (["--router", "r 1=10.0.0.5"], "router name 'r 1': use 1-63 letters"),
    (["--sign", "farm-d.csr"], "--sign 'farm-d.csr': expected ROLE:FILE.csr"),
])
def test_certs_mistakes_leave_no_ca_behind(capsys, tmp_path, args, message):
    out = tmp_path / "certs"
    assert main(["certs", "--out", str(out), *args]) == 2
    assert message in one_error_line(capsys)
    assert not out.exists()  # no CA made for a command that was refused


def test_certs_out_that_is_a_file_is_named(capsys, tmp_path):
    out = tmp_path / "certs"
    out.write_text("")
    assert main(["certs", "--out", str(out), "--gateway", "f1"]) == 2
    assert f"--out {out}: exists and is not a folder" in one_error_line(capsys)


def test_status_connect_without_a_protocol_is_said_in_words(capsys):
    assert main(["status", "--once", "--connect", "192.168.1.20:7447"]) == 2
    line = one_error_line(capsys)
    assert "--connect '192.168.1.20:7447': expected PROTOCOL/ADDRESS" in line
    assert "Json5Err" not in line


@pytest.mark.parametrize("args,message", [
    (["--from", "2026-03-02T00:00Z", "--to", "2026-03-01T00:00Z"],
     "--to 2026-03-01T00:00Z: not after --from 2026-03-02T00:00Z"),
    (["--out", "."], "--out .: is a folder"),
])
def test_export_span_and_out_mistakes_come_before_the_store(capsys, tmp_path, args, message):
    out = ["--out", str(tmp_path / "k.csv")] if "--out" not in args else []
    assert main(["export", "--db", str(tmp_path / "none.db"), *out, *args]) == 2
    assert message in one_error_line(capsys)


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


def _numeric_options_without_default(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _numeric_options_without_default(sub, f"{prefix}{name} ")
        elif (action.option_strings and action.type not in (None, str)
              and action.default not in (None, argparse.SUPPRESS, False)
              and action.help != argparse.SUPPRESS):
            d, text = action.default, action.help or ""
            shown = ["%(default)", f"({d})", f"default {d}", f"default: {d}"]
            if isinstance(d, int | float):
                shown += [f"({d:g})", f"default {d:g}", f"default: {d:g}"]
            if not any(s in text for s in shown):
                yield f"{prefix}{action.option_strings[0]}"


def test_every_numeric_option_with_a_default_shows_it_in_help():
    from gateway.cli import build_parser
    from gateway.ingest.service import build_parser as ingest_parser
    from training.appliance.cli import add_parser as run_parser
    from training.simulate.cli import add_parser as simulate_parser
    from training.vsensor.cli import build_parser as vsensor_parser

    training = argparse.ArgumentParser()
    sub = training.add_subparsers()
    simulate_parser(sub)
    run_parser(sub)
    parsers = [build_parser(), ingest_parser(), vsensor_parser(), training]
    assert [o for p in parsers for o in _numeric_options_without_default(p)] == []


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


def test_subscribe_says_its_counters_in_words(capsys, tmp_path):
    assert main(["subscribe", "--connect", "tcp/127.0.0.1:1", "--db", str(tmp_path / "c.db"),
                 "--duration", "0.3"]) == 0
    err = capsys.readouterr().err
    assert "subscribe stopped: received 0, stored 0, repeats 0" in err
    assert "SubscribeStats(" not in err


def test_a_rejected_packet_is_logged_with_its_sender_as_host_port(caplog, tmp_path):
    import logging

    from gateway.ingest.core import IngestCore, peer_text
    from gateway.store import Store

    core = IngestCore(Store(tmp_path / "g.db"), {7: b"\x00" * 32})
    with caplog.at_level(logging.WARNING, logger="serra.ingest"):
        core.handle(b"hello", ("192.168.4.7", 40000), lambda data, peer: None)
    assert "packet from 192.168.4.7:40000 rejected: short 5 bytes" in caplog.text
    assert peer_text(("fe80::1", 5683, 0, 0)) == "[fe80::1]:5683"
    assert peer_text("/dev/ttyUSB0") == "/dev/ttyUSB0"
    core.store.close()


def test_bench_runner_lists_its_benches_and_refuses_an_unknown_one():
    import subprocess
    import sys

    run = Path(__file__).parent / "bench" / "run.py"
    r = subprocess.run([sys.executable, str(run), "--help"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0 and "calibration" in r.stdout and "failed" not in r.stderr
    r = subprocess.run([sys.executable, str(run), "calibratoin"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "no bench named calibratoin (benches: " in r.stderr
    assert "== bench" not in r.stdout  # nothing was started


def test_images_build_out_that_is_a_file_is_a_usage_error(tmp_path):
    import subprocess
    import sys

    build = Path(__file__).parents[1] / "images" / "build.py"
    out = tmp_path / "build"
    out.write_text("keep me")
    r = subprocess.run([sys.executable, str(build), "--out", str(out)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2 and f"--out {out}: exists and is not a folder" in r.stderr
    assert "Traceback" not in r.stderr and out.read_text() == "keep me"


@pytest.mark.parametrize("command,option", [
    (["replay"], "--out"),
    (["replay"], "--plot"),
    (["calibrate", "--iterations", "1", "--population", "2"], "--out"),
])
def test_an_output_that_is_the_input_data_is_refused(capsys, tmp_path, command, option):
    data = kit_csv(tmp_path)
    before = data.read_bytes()
    assert main([*command, "--data", str(data), *PROTO, option, str(data)]) == 2
    assert f"{option} {data}: is the --data input" in one_error_line(capsys)
    assert data.read_bytes() == before


def test_export_over_its_own_store_is_refused(capsys, tmp_path):
    from gateway.store import Store

    db = tmp_path / "serra.db"
    Store(db).close()
    before = db.read_bytes()
    assert main(["export", "--db", str(db), "--out", str(db)]) == 2
    assert f"--out {db}: is the store --db" in one_error_line(capsys)
    assert db.read_bytes() == before

"""A new user's mistakes on where the commands write: an output in a missing folder, a folder, a file
where a folder goes, the input itself or the store being read; each is one line, exit status 2,
said before the work (not after an hour of calibration) and leaving nothing behind."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.cli import main
from tests.cli_mistakes_common import PROTO, kit_csv, one_error_line


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


def test_simulate_into_a_folder_is_named_before_simulating(capsys, tmp_path):
    from training.__main__ import main as training_main

    assert training_main(["simulate", "--out", str(tmp_path), "--days", "0.01"]) == 2
    assert f"--out {tmp_path}: is a folder" in one_error_line(capsys)


def test_subscribe_export_from_a_mistyped_store_creates_nothing(capsys, tmp_path):
    db = tmp_path / "clod.db"
    assert main(["subscribe", "--db", str(db), "--export", str(tmp_path / "csv")]) == 2
    assert f"{db}: no such cloud store" in one_error_line(capsys)
    assert not db.exists() and not (tmp_path / "csv").exists()


@pytest.mark.parametrize("args,message", [
    (["--gateway", "bad farm!"], "gateway name 'bad farm!': use 1-63 letters"),
    (["--router", "r 1=10.0.0.5"], "router name 'r 1': use 1-63 letters"),
    (["--sign", "farm-d.csr"], "--sign 'farm-d.csr': expected ROLE:FILE.csr"),
    # a router's hosts as endpoints: signed as DNS names no client matches, TLS failing far away
    (["--router", "r1=10.0.0.5:7447"],
     "--router 'r1=10.0.0.5:7447': host '10.0.0.5:7447': give the host without the port"),
    (["--router", "r1=cloud.example.org,tls/cloud.example.org:7447"],
     "host 'tls/cloud.example.org:7447': give the host alone, without the protocol"),
    (["--router", "r1=cloud example"], "host 'cloud example': not an IP address or a host name"),
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


@pytest.mark.parametrize("args,message", [
    (["--from", "2026-03-02T00:00Z", "--to", "2026-03-01T00:00Z"],
     "--to 2026-03-01T00:00Z: not after --from 2026-03-02T00:00Z"),
    (["--out", "."], "--out .: is a folder"),
])
def test_export_span_and_out_mistakes_come_before_the_store(capsys, tmp_path, args, message):
    out = ["--out", str(tmp_path / "k.csv")] if "--out" not in args else []
    assert main(["export", "--db", str(tmp_path / "none.db"), *out, *args]) == 2
    assert message in one_error_line(capsys)


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


def test_a_plot_name_matplotlib_cannot_write_is_refused_before_the_replay(capsys, tmp_path):
    data, plot = kit_csv(tmp_path), tmp_path / "replay.txt"
    assert main(["replay", "--data", str(data), *PROTO, "--plot", str(plot)]) == 2
    captured = capsys.readouterr()
    line = captured.err.strip().splitlines()[-1]
    assert line.startswith(f"error: --plot {plot}: cannot draw a '.txt' file") and "png" in line
    assert "Traceback" not in captured.err
    assert captured.out == "" and not plot.exists()  # refused before the replay, not after it


@pytest.mark.parametrize("subscribing", [False, True])
def test_subscribe_export_into_a_file_is_refused_before_subscribing(capsys, tmp_path, subscribing):
    """'--export notes.txt' (a file where the CSVs' folder goes) was a FileExistsError traceback,
    when subscribed at the end of the whole run."""
    from gateway.cloud.store import open_store

    db, export = tmp_path / "cloud.db", tmp_path / "notes.txt"
    export.write_text("keep me")
    if not subscribing:
        open_store(db, None, "serra").close()  # export only reads an existing store
    before = sorted(tmp_path.iterdir())
    link = ["--connect", "tcp/127.0.0.1:1", "--duration", "0.3"] if subscribing else []
    assert main(["subscribe", *link, "--db", str(db), "--export", str(export)]) == 2
    assert one_error_line(capsys) == f"error: --export {export}: exists and is not a folder"
    assert sorted(tmp_path.iterdir()) == before and export.read_text() == "keep me"


@pytest.mark.parametrize("subscribing", [False, True])
def test_subscribe_on_the_gateways_own_store_is_refused_and_leaves_it_unchanged(capsys, tmp_path,
                                                                                subscribing):
    """'--db serra.db' (the gateway's store) for the cloud store: the subscriber added its table
    to it and said 'no measurement stored yet'; subscribed, it would have stored into it."""
    from gateway.store import Store

    db = tmp_path / "serra.db"
    Store(db).close()
    before = db.read_bytes()
    link = ["--connect", "tcp/127.0.0.1:1", "--duration", "0.3"] if subscribing else []
    # 78 (EX_CONFIG): the setting names another database, no restart can help
    assert main(["subscribe", *link, "--db", str(db), "--export", str(tmp_path / "csv")]) == 78
    line = one_error_line(capsys)
    assert line.startswith(f"error: {db}: not a cloud store: it holds other tables (")
    assert "devices, " in line  # a table of the gateway's store, named
    assert "(the gateway's own store? 'python -m gateway export' reads that)" in line
    assert db.read_bytes() == before and not (tmp_path / "csv").exists()


@pytest.mark.parametrize("command", [["export", "--out", "x.csv"], ["status", "--once"]])
def test_the_cloud_store_given_to_a_gateway_store_reader_says_what_reads_it(capsys, tmp_path,
                                                                          command):
    from gateway.cloud.store import open_store

    db = tmp_path / "cloud.db"
    open_store(db, None, "serra").close()
    before = db.read_bytes()
    assert main([command[0], "--db", str(db), *command[1:]]) == 2
    assert one_error_line(capsys).endswith(
        "missing tables devices, meta, minute, samples) (a cloud store, which 'python -m gateway "
        "subscribe --db ... --export DIR' reads)")
    assert db.read_bytes() == before


@pytest.mark.parametrize("args", [
    ["calibrate", "--iterations", "1", "--out", "-"],
    ["replay", "--out", "-"],
    ["replay", "--plot", "-"],
    ["diagnose", "--report", "-"],
    ["vsensor", "--out", "-"],
    ["certs", "--out", "-", "--client", "c"],
    ["subscribe", "--export", "-", "--connect", "tcp/127.0.0.1:1"],
])
def test_dash_is_not_stdout_and_is_refused_naming_the_option(capsys, tmp_path, monkeypatch, args):
    """``--out -`` made a file named '-' (after the whole run): these outputs are files or
    folders beside the report stdout carries, so '-' is one line naming the option, before the
    work. (export --out - writes its CSV on stdout: tests/test_export.py.)"""
    monkeypatch.chdir(tmp_path)  # where a file named '-' would have appeared
    data = kit_csv(tmp_path)
    option = args[args.index("-") - 1]
    command = [*args, "--data", str(data), *PROTO] if args[0] not in ("certs", "subscribe") else args
    if args[0] == "vsensor":
        command = [*args, "--data", str(data), "--greenhouse", "biskra-prototype",
                   "--model-kind", "prototype"]
    assert main(command) == 2
    assert one_error_line(capsys).startswith(f"error: {option} -: this output is not written to stdout")
    assert not (tmp_path / "-").exists()


def test_training_outputs_refuse_dash_naming_the_option(capsys, tmp_path, monkeypatch):
    from training.__main__ import main as training_main
    from training.vsensor.cli import main as vsensor_main

    monkeypatch.chdir(tmp_path)
    assert training_main(["simulate", "--out", "-", "--days", "0.01"]) == 2
    assert one_error_line(capsys).startswith("error: --out -: the simulator writes the kit CSV")
    data = kit_csv(tmp_path)
    assert vsensor_main(["train", "--data", str(data), "--greenhouse", "biskra-prototype",
                         "--model", "prototype", "--out", "-"]) == 2
    assert one_error_line(capsys).startswith("error: --out -: this output is not written to stdout")
    with pytest.raises(SystemExit):
        training_main(["demo", "--out", "-"])
    assert "- is not written to stdout" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.csv"]

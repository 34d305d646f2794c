import json

import numpy as np
import pytest

from gateway.cli import main
from gateway.kitcsv import write_kit_csv
from training.identifiability import DATASET

METRIC_KEYS = {"mae", "rmse", "maxae", "r2", "ef"}


def test_calibrate_json_report_and_params_file(capsys, tmp_path):
    out = tmp_path / "p.toml"
    code = main([
        "calibrate", "--data", str(DATASET), "--greenhouse", "biskra-prototype",
        "--model", "prototype", "--algorithm", "riwpso", "--iterations", "60",
        "--calibrate-on", "2009-10-20/2009-10-21", "--json", "--out", str(out),
    ])
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert report["model"] == "prototype" and report["algorithm"] == "riwpso"
    assert set(report["params"]) == {"c_solar", "c_cnv_cnd", "c_loss", "c_thermal"}
    for part in ("calibration", "validation"):
        for mode in ("one_step", "free_run"):
            assert METRIC_KEYS <= set(report["metrics"][part][mode])
    assert report["metrics"]["validation"]["one_step"]["n"] == 1439  # the second day
    for part in ("calibration", "validation"):  # the naive baseline stands beside the model
        m = report["metrics"][part]
        assert m["persistence"]["n"] == m["one_step"]["n"]
        assert m["one_step"]["mae"] < m["persistence"]["mae"]  # noise-free data, fitted model
    assert report["seconds"] > 0
    assert "[params]" in out.read_text() and 'model = "prototype"' in out.read_text()


def test_calibrate_without_held_out_data_reports_null_validation(capsys):
    main(["calibrate", "--data", str(DATASET), "--greenhouse", "biskra-prototype", "--model",
          "prototype", "--algorithm", "rsba", "--iterations", "5", "--json"])
    assert json.loads(capsys.readouterr().out)["metrics"]["validation"] is None


def test_bad_file_gives_one_clear_line_and_exit_2(capsys, tmp_path):
    path = tmp_path / "k.csv"
    path.write_text("time,t_in,rh_in,t_out,i_glob,wind\n2020-01-01T00:00:00Z,293.15,50,10,0,1\n")
    assert main(["calibrate", "--data", str(path), "--greenhouse", "biskra-prototype",
                 "--model", "prototype"]) == 2
    err = capsys.readouterr().err
    assert "k.csv:2: column t_in" in err and "kelvin" in err


def test_missing_model_column_is_named(capsys, tmp_path):
    t = np.datetime64("2020-01-01T00:00:00", "s") + np.arange(5) * np.timedelta64(60, "s")
    cols = {c: np.full(5, 10.0) for c in ("t_in", "rh_in", "t_out", "i_glob", "wind")}
    path = write_kit_csv(tmp_path / "noso.csv", t, cols)
    assert main(["calibrate", "--data", str(path), "--greenhouse", "almeria-palmerillas",
                 "--model", "almeria"]) == 2
    assert "t_soil" in capsys.readouterr().err


@pytest.mark.parametrize("span", ["2030-01-01/2030-01-02", "yesterday"])
def test_bad_span_is_explained(capsys, span):
    assert main(["calibrate", "--data", str(DATASET), "--greenhouse", "biskra-prototype",
                 "--model", "prototype", "--calibrate-on", span]) == 2
    assert "--calibrate-on" in capsys.readouterr().err


def test_ingest_subcommand_hands_its_arguments_to_the_service(capsys, tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("7 " + "00" * 32 + "\n")
    keys.chmod(0o644)  # world-readable: the service must refuse it
    code = main(["ingest", "--db", str(tmp_path / "s.db"), "--keys", str(keys)])
    assert code == 78  # EX_CONFIG: a config error, which the shipped unit does not restart on
    assert "keys.txt" in capsys.readouterr().err


BAR_ITERATIONS = 40
"""RSBA iterations of the progress-bar runs: seconds of drawing at rich's 10 frames per second
(200 took ~20 s of the suite for the same two checks)."""


def _run_with_stderr(stderr_is_terminal: bool) -> tuple[int, str, str]:
    """Run calibrate in a child process, stderr on a pseudo-terminal or on a pipe."""
    import os
    import pty
    import select
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "gateway", "calibrate", "--data", str(DATASET), "--greenhouse",
           "biskra-prototype", "--model", "prototype", "--algorithm", "rsba",
           "--iterations", str(BAR_ITERATIONS), "--json"]
    env = {**os.environ, "COLUMNS": "120", "TERM": "xterm"}
    if not stderr_is_terminal:
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
        return p.returncode, p.stdout, p.stderr
    master, slave = pty.openpty()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, env=env)
    os.close(slave)
    screen = b""
    while True:  # drain the terminal until the child closes it
        ready, _, _ = select.select([master], [], [], 300)
        if not ready:
            break
        try:
            chunk = os.read(master, 65536)
        except OSError:  # EIO: the child exited and closed its end
            break
        if not chunk:
            break
        screen += chunk
    out = proc.stdout.read().decode() if proc.stdout else ""
    os.close(master)
    return proc.wait(timeout=60), out, screen.decode(errors="replace")


def test_progress_bar_on_a_terminal_and_plain_lines_when_piped():
    code, out, screen = _run_with_stderr(True)
    assert code == 0 and json.loads(out)["algorithm"] == "rsba"
    assert f"/{BAR_ITERATIONS}" in screen and "MSE" in screen, screen[-500:]  # the bar was drawn
    assert "progress: " not in screen  # the bar, not the log's lines
    code, out, err = _run_with_stderr(False)
    assert code == 0 and json.loads(out)["algorithm"] == "rsba"
    # a pipe: the log's lines (tests/test_cli_progress.py), no escape codes
    assert f"100 % ({BAR_ITERATIONS}/{BAR_ITERATIONS})" in err and "\x1b[" not in err


@pytest.mark.parametrize("rows", [1, 3])
@pytest.mark.parametrize("command", ["calibrate", "replay", "diagnose"])
def test_too_short_data_is_one_clear_line_not_a_traceback(capsys, tmp_path, command, rows):
    t = np.datetime64("2020-01-01T00:00:00", "s") + np.arange(rows) * np.timedelta64(60, "s")
    cols = {c: np.full(rows, 10.0) for c in ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind")}
    path = write_kit_csv(tmp_path / "short.csv", t, cols)  # all kit columns: no note on stderr
    code = main([command, "--data", str(path), "--greenhouse", "biskra-prototype", "-q",
                 "--model", "prototype", "--iterations" if command == "calibrate" else "--seed", "1"])
    err = capsys.readouterr().err  # -q: the progress lines of a pipe left out
    assert (code, err.count("\n")) == ((0, 0) if rows == 3 and command != "diagnose" else (2, 1)), err
    assert code == 0 or "short.csv" in err


def test_required_column_present_but_empty_is_named_as_empty(capsys, tmp_path):
    t = np.datetime64("2020-01-01T00:00:00", "s") + np.arange(5) * np.timedelta64(60, "s")
    cols = {c: np.full(5, 10.0) for c in ("t_in", "rh_in", "t_out", "i_glob")} | {"wind": np.full(5, np.nan)}
    path = write_kit_csv(tmp_path / "nowind.csv", t, cols)
    assert main(["calibrate", "--data", str(path), "--greenhouse", "biskra-prototype",
                 "--model", "prototype"]) == 2
    assert "nowind.csv: column(s) wind hold no value" in capsys.readouterr().err


@pytest.mark.parametrize("step", ["0", "-60", "nan"])
def test_step_must_be_positive(capsys, step):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--data", str(DATASET), "--greenhouse", "biskra-prototype",
              "--model", "prototype", f"--step={step}"])
    assert exc.value.code == 2
    assert "--step: must be a positive number" in capsys.readouterr().err


@pytest.mark.parametrize("arg", ["--iterations=0", "--population=0", "--iterations=-3"])
def test_iterations_and_population_must_be_at_least_one(capsys, arg):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--data", str(DATASET), "--greenhouse", "biskra-prototype",
              "--model", "prototype", arg])
    assert exc.value.code == 2
    assert "must be at least 1" in capsys.readouterr().err



@pytest.mark.parametrize("command", ["calibrate", "replay", "diagnose", "vsensor"])
@pytest.mark.parametrize(("seed", "why"), [("-1", "must be 0 or more, got '-1'"),
                                           ("1.5", "not a whole number: '1.5'")])
def test_a_seed_numpy_would_refuse_is_a_usage_error_not_a_traceback(capsys, command, seed, why):
    kind = ["--model-kind", "prototype"] if command == "vsensor" else ["--model", "prototype"]
    with pytest.raises(SystemExit) as exc:  # before the data is read: argparse's exit 2
        main([command, "--data", str(DATASET), "--greenhouse", "biskra-prototype", *kind,
              f"--seed={seed}"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.splitlines()[-1].endswith(f"error: argument --seed: {why}")


def test_the_params_files_header_is_the_whole_command_and_makes_the_same_file(capsys, tmp_path):
    """The header said only '--algorithm rsba --seed 0 on FILE': the greenhouse, model, span and
    search size that made the numbers were lost with the terminal."""
    import shlex

    from tests.cli_mistakes_common import kit_csv

    data, first, again = kit_csv(tmp_path, rows=90), tmp_path / "p.toml", tmp_path / "again.toml"
    assert main(["calibrate", "--data", str(data), "--greenhouse", "biskra-prototype", "--model",
                 "prototype", "--calibrate-on", "2020-03-27T10:00/2020-03-27T11:00",
                 "--iterations", "2", "--population", "3", "--site", "52,4.5", "--seed", "3",
                 "--out", str(first)]) == 0
    header = first.read_text().splitlines()[0]
    words = shlex.split(header.removeprefix("# "))
    assert words[:4] == ["python", "-m", "gateway", "calibrate"]
    for option, value in (("--greenhouse", "biskra-prototype"), ("--seed", "3"),
                          ("--calibrate-on", "2020-03-27T10:00/2020-03-27T11:00"),
                          ("--iterations", "2"), ("--population", "3"), ("--site", "52,4.5")):
        assert words[words.index(option) + 1] == value, header
    assert main([*words[3:], "--out", str(again)]) == 0
    capsys.readouterr()
    assert again.read_text() == first.read_text()


def test_a_population_no_machine_holds_is_one_line_not_numpys_traceback(capsys, tmp_path):
    from tests.cli_mistakes_common import kit_csv

    data = kit_csv(tmp_path)  # 10^12 particles: ~29 TiB, refused at once by the allocator
    assert main(["calibrate", "--data", str(data), "--greenhouse", "biskra-prototype", "--model",
                 "prototype", "--iterations", "1", "--population", "1000000000000"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert line.startswith("error: calibrate: out of memory (Unable to allocate")
    assert line.endswith("a smaller --population, window or span)")

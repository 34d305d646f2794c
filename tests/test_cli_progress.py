"""Progress of the long commands when stderr is a pipe (cron, CI logs): plain ``progress:`` lines
on stderr at each tenth of the work, no ANSI and no carriage return, stdout the results only;
``-q`` silences them (gateway/cli/progress.py). The terminal's bar: test_cli_calibrate.py."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys

import pytest

from gateway.cli.progress import PlainProgress, stage_printer
from tests.cli_mistakes_common import PROTO
from training.identifiability import DATASET

LINE = re.compile(r"progress: (?P<label>.+?) (?P<pct>\d+) % \((?P<done>\d+)/(?P<total>\d+)\), \d+ s")


def _piped(*args: str) -> subprocess.CompletedProcess:
    """``python -m gateway ARGS`` with stdout and stderr on pipes, as in a cron job."""
    return subprocess.run([sys.executable, "-m", "gateway", *args], capture_output=True,
                          text=True, timeout=600, env={**os.environ, "TERM": "xterm"})


def _progress(err: str) -> list[re.Match]:
    assert "\x1b" not in err and "\r" not in err, err[-500:]  # a log, not a screen
    return [m for m in map(LINE.match, err.splitlines()) if m]


def _tenths(found: list[re.Match]) -> list[int]:
    pcts = [int(m["pct"]) for m in found]
    assert pcts == sorted(pcts), pcts  # wall-clock lines between tenths never go back
    return sorted({p // 10 * 10 for p in pcts})


def test_calibrate_piped_says_each_tenth_on_stderr_and_only_json_on_stdout():
    r = _piped("calibrate", "--data", str(DATASET), *PROTO, "--algorithm", "rsba",
               "--iterations", "20", "--population", "6", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["algorithm"] == "rsba"  # stdout is the result, whole
    found = _progress(r.stderr)
    assert _tenths(found) == list(range(10, 101, 10)), r.stderr
    assert {m["label"] for m in found} == {"rsba prototype"} and found[-1]["done"] == "20"
    assert re.fullmatch(r"progress: rsba prototype done, \d+ s", r.stderr.splitlines()[-1])
    assert "MSE" in r.stderr


def test_replay_piped_says_its_rows():
    r = _piped("replay", "--data", str(DATASET), *PROTO, "--set", "t_in.iterations=2",
               "--set", "t_in.bats=4")
    assert r.returncode == 0, r.stderr
    assert "progress:" not in r.stdout and "replay of" in r.stdout
    found = _progress(r.stderr)  # said every 100 rows of 2880: the last tenth by the done line
    assert _tenths(found) == list(range(10, 91, 10)), r.stderr
    assert found[-1]["total"] == "2880"
    assert re.fullmatch(r"progress: replay prototype done, \d+ s", r.stderr.splitlines()[-1])


def test_diagnose_piped_says_its_stages():
    r = _piped("diagnose", "--data", str(DATASET), *PROTO, "--json")
    assert r.returncode == 0, r.stderr
    json.loads(r.stdout)
    stages = [ln for ln in r.stderr.splitlines() if ln.startswith("progress: diagnose: ")]
    assert stages[0].startswith("progress: diagnose: calibrating the base model"), r.stderr
    assert any("round 1: ranking" in ln for ln in stages), r.stderr
    assert "\x1b" not in r.stderr and "\r" not in r.stderr


@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_leaves_stderr_to_notes_and_errors(where: str):
    args = ["calibrate", "--data", str(DATASET), *PROTO, "--iterations", "5", "--population", "4"]
    r = _piped(*(["-q", *args] if where == "before" else [*args, "--quiet"]))
    assert r.returncode == 0 and "calibrated with" in r.stdout
    assert r.stderr == ""


def test_plain_lines_come_at_each_tenth_and_after_a_silence_of_the_pace():
    """Counted on a clock the test moves: a line per tenth crossed, and one more each time
    ``pace_s`` passes without one (a replay inside train advances nothing for minutes)."""
    now = [0.0]
    out = io.StringIO()
    bar = PlainProgress("work", 200, out, clock=lambda: now[0], pace_s=30.0)
    for _ in range(200):  # never 30 s between calls: the tenths alone
        bar()
    assert len(out.getvalue().splitlines()) == 10
    out.truncate(0)
    out.seek(0)
    slow = PlainProgress("slow", 10, out, clock=lambda: now[0], pace_s=30.0)
    for _ in range(7):  # no work done, 20 s per call: a line at 40 s, 80 s and 120 s
        now[0] += 20.0
        slow(advance=0, info="row 100")
    lines = out.getvalue().splitlines()
    assert lines == [f"progress: slow 0 % (0/10), {s} s (row 100)" for s in (40, 80, 120)]


def test_stages_are_indented_on_a_terminal_and_labelled_in_a_log():
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    screen, log = Tty(), io.StringIO()
    stage_printer("diagnose", stream=screen)("round 1")
    stage_printer("diagnose", stream=log, clock=lambda: 0.0)("round 1")
    stage_printer("diagnose", quiet=True, stream=log)("never")
    assert screen.getvalue() == "  round 1\n"
    assert log.getvalue() == "progress: diagnose: round 1, 0 s\n"


def test_vsensor_dataset_piped_counts_its_files(capsys):
    """``python -m training.vsensor dataset`` (the test files' cached replays, built once for the
    run by tests/vsensor_data.py): a line per file on stderr, the per-file results on stdout."""
    from tests import vsensor_data as vd
    from training.vsensor.cli import main

    paths = [str(p) for p in vd.train_files()]
    sets = [a for part, opts in vd.TINY.items() for k, v in opts.items()
            for a in ("--set", f"{part}.{k}={v}")]
    assert main(["dataset", "--data", *paths, "--greenhouse", vd.GREENHOUSE, "--model", "almeria",
                 "--cache", str(vd.workdir() / "cache"), *sets]) == 0
    out, err = capsys.readouterr()
    found = _progress(err)
    assert [(m["pct"], m["done"]) for m in found if m["label"] == "dataset"] == [("50", "1"), ("100", "2")]
    assert err.splitlines()[-1].startswith("progress: dataset done, ")
    assert "progress" not in out and len(out.splitlines()) == 2


def _vsensor(capsys, *argv: str) -> tuple[str, str, str]:
    """``python -m training.vsensor ARGV`` in this process (stderr captured: not a terminal),
    then again with ``-q``: (stdout, stderr, the quiet run's stderr); the two stdouts equal
    but for the times some commands print."""
    from training.vsensor.cli import main

    capsys.readouterr()
    assert main(list(argv)) == 0
    out, err = capsys.readouterr()
    assert main([*argv, "-q"]) == 0
    quiet_out, quiet_err = capsys.readouterr()
    timeless = [re.sub(r"in [\d.]+ s", "in - s", o) for o in (out, quiet_out)]
    assert timeless[0] == timeless[1] and "progress" not in out
    return out, err, quiet_err


def _counted(err: str, label: str) -> list[tuple[str, str]]:
    """(percent, done) of each ``label`` line, in order, a repeat (a 30-s line under load) once."""
    found = [(m["pct"], m["done"]) for m in _progress(err) if m["label"] == label]
    assert err.splitlines()[-1].startswith(f"progress: {label} done, "), err
    return list(dict.fromkeys(found))


def _tiny_args() -> list[str]:
    from tests import vsensor_data as vd

    return ["--greenhouse", vd.GREENHOUSE, "--model", "almeria", "--cache",
            str(vd.workdir() / "cache"),
            *[a for part, opts in vd.TINY.items() for k, v in opts.items()
              for a in ("--set", f"{part}.{k}={v}")]]


def test_vsensor_errors_piped_counts_the_files_then_the_closed_loop(capsys):
    """``errors`` on the two tiny training files and the tiny sensor (tests/vsensor_data.py)."""
    from tests import vsensor_data as vd

    out, err, quiet = _vsensor(capsys, "errors", "--sensor", str(vd.tiny_model()), "--data",
                               *[str(p) for p in vd.train_files()], *_tiny_args())
    assert _counted(err, "errors") == [("33", "1"), ("66", "2"), ("100", "3")]
    assert out.startswith("by file:") and quiet == ""


def test_vsensor_score_piped_counts_each_files_replays_and_each_sensor(capsys):
    """``score`` of the tiny sensor and its linear ARX on the tiny test file."""
    from gateway.vsensor.batch import baseline_paths
    from tests import vsensor_data as vd

    model = vd.tiny_model()
    arx = baseline_paths(model)["linear_arx"]
    out, err, quiet = _vsensor(capsys, "score", "--sensor", str(model), str(arx), "--data",
                               str(vd.test_file()), *_tiny_args(), "--json")
    assert _counted(err, "score") == [("33", "1"), ("66", "2"), ("100", "3")]
    assert set(json.loads(out)["test-grower"]) == {str(model), str(arx)} and quiet == ""


def test_vsensor_reference_piped_counts_its_files(capsys):
    """``reference`` (no cache: a replay per run) on one tiny training file."""
    from tests import vsensor_data as vd

    args = [a for a in _tiny_args() if not a.startswith(("--cache", str(vd.workdir())))]
    out, err, quiet = _vsensor(capsys, "reference", "--data", str(vd.train_files()[0]), *args)
    assert _counted(err, "reference") == [("100", "1")]
    assert out.startswith("train-grower.csv: ") and quiet == ""


def test_vsensor_corpus_piped_counts_its_runs(capsys, tmp_path):
    """``corpus --only`` two of the real runs (the simulator: well under a second each)."""
    runs = ["other-house-spring", "biskra-spring-controller"]
    out, err, quiet = _vsensor(capsys, "corpus", "--out", str(tmp_path), "--only", *runs)
    assert _counted(err, "corpus") == [("50", "1"), ("100", "2")]
    assert [ln.split()[0] for ln in out.splitlines()] == ["wrote", "wrote", "2"] and quiet == ""

"""A demanding user's mistakes on the offline tools (python -m training, python -m training.vsensor):
each is one line naming the option, exit status 2, no traceback, refused before any work so that
nothing is left behind."""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

import pytest

from tests.cli_mistakes_common import help_pages, lines_too_wide_or_broken
from training.__main__ import main as training_main
from training.vsensor.cli import main as vsensor_main

TRAIN = ["train", "--greenhouse", "almeria-palmerillas", "--model", "almeria"]


def _refused(capsys, run, argv: list[str]) -> str:
    """The argparse refusal of ``argv``: exit status 2, its one error line (no traceback)."""
    with pytest.raises(SystemExit) as exc:
        run(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize("argv", [
    ["simulate", "--days", "0.01"],
    ["demo", "--days", "3"],
])
def test_a_negative_seed_is_named_before_the_run(capsys, tmp_path, argv):
    out = tmp_path / "out" / ("run.csv" if argv[0] == "simulate" else "demo")
    line = _refused(capsys, training_main, [*argv, "--seed", "-1", "--out", str(out)])
    assert "argument --seed: must be 0 or more, got '-1'" in line
    assert not (tmp_path / "out").exists()  # the demo made its folder, then a traceback


@pytest.mark.parametrize("option", ["--seed", "--net-seed"])
def test_vsensor_train_names_a_negative_seed(capsys, tmp_path, option):
    csv = Path(tmp_path / "k.csv")
    csv.write_text("time,t_in\n")  # never read: the option is refused first
    line = _refused(capsys, vsensor_main, [*TRAIN, "--data", str(csv), option, "-1",
                                           "--out", str(tmp_path / "m.onnx")])
    assert f"argument {option}: must be 0 or more, got '-1'" in line


@pytest.mark.parametrize("option,value,says", [
    ("--epochs", "0", "must be at least 1"),  # was sklearn's AttributeError after the replays
    ("--ensemble", "0", "must be at least 1"),
    ("--rounds", "-1", "must be 0 or more"),  # was silently none
    ("--round-lr", "0", "must be a positive number"),
    ("--high-flow-weight", "-1", "must be a positive number"),  # was a negative loss weight
])
def test_vsensor_train_names_a_setting_it_cannot_fit_with(capsys, tmp_path, option, value, says):
    line = _refused(capsys, vsensor_main, [*TRAIN, "--data", str(tmp_path / "k.csv"), option, value,
                                           "--out", str(tmp_path / "m.onnx")])
    assert f"argument {option}: {says}, got '{value}'" in line


def test_vsensor_train_refuses_its_outputs_before_the_training(capsys, tmp_path):
    """Both were refused after the fit (minutes to hours), the models already written."""
    data = tmp_path / "k.csv"
    data.write_text("not a kit CSV\n")  # never read: the outputs are checked first
    assert vsensor_main([*TRAIN, "--data", str(data), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"error: --out {tmp_path}: is a folder; give the sensor's file name (MODEL.onnx)"
    out = tmp_path / "models" / "m.onnx"
    assert vsensor_main([*TRAIN, "--data", str(data), "--out", str(out), "--report", str(data)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"error: --report {data}: exists and is not a folder"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.csv"]


def test_vsensor_corpus_refuses_before_simulating(capsys, tmp_path):
    """A file where the corpus folder goes was said as "<out>/test: Not a directory" (not the
    option); a bare ``--only`` wrote nothing and said "0 runs", exit status 0."""
    taken = tmp_path / "corpus"
    taken.write_text("")
    assert vsensor_main(["corpus", "--out", str(taken), "--only", "biskra-spring-grower"]) == 2
    assert capsys.readouterr().err.strip() == f"error: --out {taken}: exists and is not a folder"
    assert vsensor_main(["corpus", "--out", str(tmp_path / "c"), "--only"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --only: name at least one run (runs: almeria-winter-controller, ")
    assert len(err.splitlines()) == 1 and not (tmp_path / "c").exists()


@pytest.mark.parametrize("command", ["score", "errors"])
def test_vsensor_names_a_missing_sensor_before_the_replays(capsys, tmp_path, command):
    data = tmp_path / "k.csv"
    data.write_text("not a kit CSV\n")  # never read: the sensor is checked first
    for sensor, says in ((tmp_path / "none.onnx", "no such file"),
                         (tmp_path, "is a folder, not an ONNX file")):
        assert vsensor_main([command, "--data", str(data), *TRAIN[1:], "--cache",
                             str(tmp_path / "cache"), "--sensor", str(sensor)]) == 2
        assert capsys.readouterr().err.strip() == f"error: --sensor {sensor}: {says}"
    assert not (tmp_path / "cache").exists()


def test_demo_heater_names_an_output_that_is_a_file(capsys, tmp_path):
    """It was os.mkdir's FileExistsError traceback."""
    from training.demo_heater import main

    taken = tmp_path / "runs"
    taken.write_text("")
    line = _refused(capsys, main, ["--out", str(taken)])
    assert line == (f"python -m training.demo_heater: error: argument --out: {taken} exists and "
                    "is not a folder")


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_step_bias_refuses_a_step_it_cannot_integrate_with(capsys, value):
    """--h 0 was a ZeroDivisionError after the reference weather was built."""
    from training.step_bias import main

    line = _refused(capsys, main, ["--h", value])
    assert line.endswith(f"argument --h: must be a positive number, got '{value}'")


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """Every subcommand parser of python -m training and python -m training.vsensor."""
    from training.__main__ import COMMANDS
    from training.vsensor.cli import build_parser

    sub = argparse.ArgumentParser().add_subparsers()
    for module in COMMANDS:
        importlib.import_module(module).add_parser(sub)
    parsers = dict(sub.choices)
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            parsers.update({f"vsensor {k}": v for k, v in action.choices.items()})
    return parsers


def test_every_option_with_a_default_says_it_as_the_gateway_does():
    """"(default X)", as python -m gateway's commands: the tools said "(default: 14)", "(0)",
    "(out/demo)" or nothing (simulate's --weather left seville out of its list)."""
    parsers = _parsers()
    assert {"simulate", "demo", "run", "vsensor corpus", "vsensor train"} <= set(parsers)
    said = []
    for name, parser in parsers.items():
        for action in parser._actions:
            default = action.default
            if (isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
                    or default in (None, "", [], argparse.SUPPRESS)):
                continue
            said.append(f"{name} {action.dest}")
            assert "default" in action.help, (name, action.option_strings)
            assert f"(default: {default})" not in action.help, (name, action.option_strings)
    assert "simulate days" in said and "vsensor train epochs" in said
    weather = next(a for a in parsers["simulate"]._actions if a.dest == "weather")
    assert all(w in weather.help for w in weather.choices)


@pytest.mark.parametrize("value", ["0.5", "1.5"])
def test_simulate_refuses_a_step_of_part_seconds(capsys, tmp_path, value):
    """0.5 s was a ZeroDivisionError (the grid's times are whole seconds: a zero step), 1.5 s an
    uneven grid simulated with a 2 s step."""
    out = tmp_path / "out" / "run.csv"
    line = _refused(capsys, training_main, ["simulate", "--days", "0.001", "--step", value,
                                            "--out", str(out)])
    assert f"argument --step: must be whole seconds (the CSV's times are), got '{value}'" in line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("spec,says", [
    ("heater@2009-13-01", "effect heater: bad start time '2009-13-01'"),  # numpy's words, no name
    ("door", "unknown effect 'door' (known effects: cover_transmission, extra_leakage, "),
    ("cover_transmission:factor=-1", "effect cover_transmission: "),
])
def test_simulate_says_a_bad_effect_in_one_line(capsys, tmp_path, spec, says):
    """The known effects were an 8-line table after the error; now their names on its line."""
    out = tmp_path / "run.csv"
    assert training_main(["simulate", "--days", "0.01", "--effect", spec, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith(f"error: {says}")
    assert "sensor_drift" in err and not out.exists()


def test_vsensor_names_a_missing_test_file_or_a_file_cache_before_the_replays(capsys, tmp_path):
    """A missing --test file was found after the fit, the models written without their card; a
    tune --log in a missing folder after the fit."""
    data = tmp_path / "k.csv"
    data.write_text("not a kit CSV\n")  # never read: the paths are checked first
    out = ["--out", str(tmp_path / "m" / "m.onnx")]
    for argv, says in (
        ([*TRAIN, "--data", str(data), *out, "--test", str(tmp_path / "no.csv")],
         f"--test {tmp_path / 'no.csv'}: no such file"),
        ([*TRAIN, "--data", str(data), *out, "--test", str(tmp_path)],
         f"--test {tmp_path}: is a folder, not a kit CSV"),
        (["dataset", *TRAIN[1:], "--data", str(data), "--cache", str(data)],
         f"--cache {data}: exists and is not a folder"),
        ([*TRAIN, "--data", str(tmp_path / "corpus" / "*.csv"), *out],  # an empty corpus folder
         f"--data {tmp_path / 'corpus' / '*.csv'}: no such file (a pattern that matched nothing: "
         "an empty or mistyped folder?)"),
        (["tune", *TRAIN[1:], "--data", str(data), "--subset", "k", "winter"],  # MAE null after it
         "--subset winter: no --data file has that stem"),
        (["tune", *TRAIN[1:], "--data", str(data), "--log", str(tmp_path / "no" / "t.jsonl")],
         f"--log {tmp_path / 'no' / 't.jsonl'}: folder {tmp_path / 'no'} does not exist"),
    ):
        assert vsensor_main(argv) == 2
        assert capsys.readouterr().err.strip() == f"error: {says}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.csv"]


def test_run_names_an_output_that_is_a_file_before_starting(capsys, tmp_path):
    """It was mkdir's FileExistsError traceback from the set-up."""
    taken = tmp_path / "run"
    taken.write_text("")
    line = _refused(capsys, training_main, ["run", "--out", str(taken), "--minutes", "1",
                                            "--screen", "no"])
    assert line == f"python -m training run: error: argument --out: {taken} exists and is not a folder"
    assert taken.read_text() == ""


def test_identifiability_names_an_output_that_is_a_folder(capsys, tmp_path):
    """It was IsADirectoryError's traceback after the dataset was built."""
    from training.identifiability import main

    line = _refused(capsys, main, ["--out", str(tmp_path)])
    assert line == (f"python -m training.identifiability: error: --out {tmp_path}: is a folder; "
                    "give the dataset's file name")
    assert list(tmp_path.iterdir()) == []


def test_vsensor_errors_names_an_only_that_matches_no_file(capsys, tmp_path):
    """It was numpy's "need at least one array to concatenate", after the replays."""
    data = tmp_path / "almeria-winter.csv"
    data.write_text("not a kit CSV\n")  # never read: --only is checked first
    assert vsensor_main(["errors", "--data", str(data), *TRAIN[1:], "--cache", str(tmp_path / "c"),
                         "--sensor", str(data), "--only", "summer"]) == 2
    assert capsys.readouterr().err.strip() == "error: --only 'summer': in no --data file's name"




def test_every_help_page_fits_80_columns_unbroken(monkeypatch):
    """At 80 columns: train's --target choices made its usage 86 wide, simulate's raw
    description and effects ran to 120, and argparse broke 'almeria-palmerillas' and
    'docs/data-format.md' at their hyphens. A default is '(default X)', never '(default: X)'."""
    from training.__main__ import build_parser as training_parser
    from training.vsensor.cli import build_parser as vsensor_parser

    monkeypatch.setenv("COLUMNS", "80")  # what argparse wraps to
    pages = {**help_pages(training_parser()), **help_pages(vsensor_parser())}
    assert len(pages) == 2 + 3 + 7  # the two tools, simulate/demo/run, the sensor's seven
    assert lines_too_wide_or_broken(pages) == []
    lines = [(name, line) for name, text in pages.items() for line in text.splitlines()]
    assert [nl for nl in lines if "(default:" in nl[1]] == []


@pytest.mark.parametrize("before,after", [([], []), (["-q"], []), ([], ["-q"]),
                                          (["--quiet"], ["--quiet"])])
def test_vsensor_quiet_is_taken_before_or_after_the_command(capsys, tmp_path, before, after):
    """'python -m training.vsensor -q corpus ...' was "unrecognized arguments: -q": only each
    command had it, after the command."""
    from training.vsensor.cli import build_parser

    parser = build_parser()
    quiet = bool(before or after)
    for command in ([*TRAIN, "--data", "k.csv", "--out", "m.onnx"], ["corpus", "--out", "c"],
                    ["score", "--data", "k.csv", *TRAIN[1:], "--sensor", "m.onnx"]):
        assert parser.parse_args([*before, *command, *after]).quiet is quiet
    # through main: the corpus's own refusal of --only, not argparse's of -q
    argv = [*before, "corpus", "--out", str(tmp_path), "--only", "nowhere", *after]
    assert vsensor_main(argv) == 2
    assert "error: --only: no run named nowhere" in capsys.readouterr().err

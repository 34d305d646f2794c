"""The data commands' model step when ``--step`` is not given: 60 s, or the rows' own spacing
when they are further apart than the tools interpolate across (10- and 15-minute loggers),
said in a ``step_from_rows`` note; a given ``--step`` always wins."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gateway.cli import main
from gateway.kitcsv import KitData, read_kit_csv, write_kit_csv
from gateway.series import DEFAULT_STEP, data_step
from tests.test_cli_notes import FAST, _greenhouse, _kit

DAYS = 2


def _rows(folder: Path, row_s: int) -> Path:
    """``DAYS`` of the notes tests' record, every ``row_s`` seconds (a multiple of 300)."""
    five = read_kit_csv(str(_kit(folder / "five.csv", DAYS)))
    k = row_s // 300
    return write_kit_csv(folder / f"rows_{row_s}.csv", five.time[::k],
                         {c: v[::k] for c, v in five.columns.items()})


def _replay(capsys, data: Path, *more: str) -> dict:
    code = main(["replay", "--data", str(data), "--greenhouse", str(_greenhouse(data.parent)),
                 "--model", "prototype", "--json", *FAST["replay"], *more])
    out, err = capsys.readouterr()
    assert code == 0 and "Traceback" not in err, err
    return json.loads(out)


def _step_notes(result: dict) -> list[str]:
    return [n["message"] for n in result["notes"] if n["code"] == "step_from_rows"]


@pytest.mark.parametrize("row_s", [600, 900])
def test_coarse_rows_run_at_their_own_step(tmp_path, capsys, row_s):
    result = _replay(capsys, _rows(tmp_path, row_s))
    # one model step per row, not 10 or 15 interpolated minutes (which would be refused)
    assert result["samples"] == DAYS * 86400 // row_s
    (message,) = _step_notes(result)
    assert f"rows_{row_s}.csv" in message and f"a {row_s} s step" in message
    # a horizon the step cannot reach is left out, and said to be; the others kept
    assert set(result["horizons"]) == ({"30", "60"} if row_s == 600 else {"15", "30", "60"})
    left = [n["message"] for n in result["notes"] if n["code"] == "horizon_left_out"]
    assert left == (["the 15-minute forecast is left out: not a whole number of 600 s model "
                     "steps"] if row_s == 600 else [])


def test_five_minute_rows_keep_the_default_step(tmp_path, capsys):
    result = _replay(capsys, _rows(tmp_path, 300))
    assert result["samples"] == DAYS * 86400 // int(DEFAULT_STEP) - 300 // int(DEFAULT_STEP) + 1
    assert _step_notes(result) == []


def test_a_given_step_wins(tmp_path, capsys):
    result = _replay(capsys, _rows(tmp_path, 900), "--step", "1800")
    assert result["samples"] == DAYS * 86400 // 1800
    assert _step_notes(result) == []


def test_a_given_step_too_fine_for_the_rows_names_the_fix(tmp_path, capsys):
    data = _rows(tmp_path, 900)
    code = main(["replay", "--data", str(data), "--greenhouse", str(_greenhouse(tmp_path)),
                 "--model", "prototype", "--step", "60"])
    err = capsys.readouterr().err
    assert code == 2 and "rows_900.csv" in err and "--step 900" in err


@pytest.mark.parametrize("spacing,step", [(60.0, 60.0), (300.0, 60.0), (320.0, 60.0),
                                          (601.0, 600.0), (590.0, 600.0), (900.0, 900.0),
                                          (3600.0, 3600.0)])
def test_the_step_taken_from_the_rows(spacing, step):
    t = (np.datetime64("2020-03-27T00:00:00", "s")
         + (np.arange(50) * spacing).astype("timedelta64[s]"))
    data = KitData(time=t, columns={"t_in": np.zeros(50)}, source="x.csv")
    assert data_step(data) == step


def test_the_virtual_sensor_says_it_needs_minutes(tmp_path, capsys):
    data = _rows(tmp_path, 900)
    code = main(["vsensor", "--data", str(data), "--greenhouse", str(_greenhouse(tmp_path)),
                 "--model-kind", "prototype"])
    err = capsys.readouterr().err
    # not the data commands' "--step 900": vsensor has no step to choose
    assert code == 2 and "rows_900.csv" in err and "60 s grid" in err and "--step" not in err

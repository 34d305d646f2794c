"""°F temperatures in a kit CSV (docs/data-format.md: °C): a cool file in °F passes the range
checks, so the reader says it looks like °F (a warning, gateway/kitcsv.py); a warmer one is
refused by the range check, whose error now says °F; hot-climate data in °C (Biskra July) is
neither. Files from the simulator on the shipped weather and the shipped identifiability file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gateway.kitcsv import KitCsvError, read_kit_csv, write_kit_csv
from training.identifiability import DATASET
from training.simulate import simulate

TEMPERATURES = ("t_in", "t_out", "t_soil")


def _in_fahrenheit(src: Path, dst: Path, only: tuple[str, ...] = TEMPERATURES) -> Path:
    data = read_kit_csv(src)
    return write_kit_csv(dst, data.time, {c: v * 1.8 + 32.0 if c in only else v
                                          for c, v in data.columns.items()})


def _fahrenheit_notices(path: Path) -> list[str]:
    return [n for n in read_kit_csv(path).notices if "looks like °F" in n]


def test_a_cool_november_in_fahrenheit_is_said_to_look_like_it(tmp_path):
    """Bleiswijk's measured weather, 14-17 November 2009: every cell within the °C ranges in °F
    (inside at most 70, outside at most 60), the medians above 45."""
    celsius = simulate("prototype", "bleiswijk", "2009-11-14", days=3.0, seed=0).write(
        tmp_path / "nov.csv")[0]
    assert _fahrenheit_notices(celsius) == []
    notices = _fahrenheit_notices(_in_fahrenheit(celsius, tmp_path / "nov_f.csv"))
    assert [n.split(": ")[1] for n in notices] == ["column t_in", "column t_out"], notices
    assert "nov_f.csv: column t_in: median 5" in notices[0] and "(°F - 32) / 1.8" in notices[0]
    # the outside from a weather service in °F beside the kit's °C inside: that column alone
    mixed = _fahrenheit_notices(_in_fahrenheit(celsius, tmp_path / "mixed.csv", ("t_out",)))
    assert [n.split(": ")[1] for n in mixed] == ["column t_out"]


def test_biskra_in_july_is_hot_in_celsius_not_fahrenheit(tmp_path):
    """The hottest house the simulator makes (the prototype in Biskra's July: inside up to
    about 57 °C at noon) reads without a word; in °F it is refused, the error saying °F."""
    celsius = simulate("prototype", "biskra", "2019-07-10", days=3.0, seed=0).write(
        tmp_path / "july.csv")[0]
    data = read_kit_csv(celsius)
    assert np.nanmax(data.columns["t_in"]) > 45.0 and data.notices == []
    with pytest.raises(KitCsvError, match=r"july_f\.csv:\d+: column t_in: .*\(°F\? the kit CSV "
                                          r"wants °C: \(°F - 32\) / 1\.8\)"):
        read_kit_csv(_in_fahrenheit(celsius, tmp_path / "july_f.csv"))


def test_the_shipped_file_in_fahrenheit_is_refused_with_the_hint(tmp_path):
    assert _fahrenheit_notices(DATASET) == []
    with pytest.raises(KitCsvError, match=r"column t_in: .* °C outside the physical range .*°F\?"):
        read_kit_csv(_in_fahrenheit(DATASET, tmp_path / "f.csv"))


def test_less_than_a_day_is_not_judged(tmp_path):
    """A few midday hours of a hot house can sit above 45 °C: no notice under a day of rows."""
    t = np.datetime64("2019-07-10T10:00:00", "s") + np.arange(300) * np.timedelta64(60, "s")
    path = write_kit_csv(tmp_path / "noon.csv", t, {"t_in": np.full(300, 52.0),
                                                     "t_out": np.full(300, 46.0)})
    assert read_kit_csv(path).notices == []


def test_the_command_line_says_it_as_a_warning(tmp_path):
    celsius = simulate("prototype", "bleiswijk", "2009-11-14", days=3.0, seed=0).write(
        tmp_path / "nov.csv")[0]
    data = _in_fahrenheit(celsius, tmp_path / "nov_f.csv")
    r = subprocess.run([sys.executable, "-m", "gateway", "calibrate", "--data", str(data),
                        "--greenhouse", "biskra-prototype", "--model", "prototype", "--iterations",
                        "2", "--population", "4", "--json", "-q"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    warned = [ln for ln in r.stderr.splitlines() if ln.startswith(f"warning: {data}: column t_")]
    assert len(warned) == 2 and "looks like °F" in warned[0], r.stderr
    notes = [n for n in json.loads(r.stdout)["notes"] if "looks like °F" in n["message"]]
    assert [(n["code"], n["level"]) for n in notes] == [("csv_reader", "warning")] * 2

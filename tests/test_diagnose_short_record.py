"""A record too short for the judge (docs/effects.md, "Known limits"): ``diagnose`` says that no
finding can come out of it, instead of a bare "no library effect improved the held-out error"
that reads as a clean bill of health."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.cli import main
from gateway.cli.notes import short_heldout_note
from gateway.diagnose import diagnose, significance
from gateway.diagnose.search import split_index
from gateway.greenhouse import load_greenhouse
from gateway.kitcsv import write_kit_csv
from gateway.model import build_model
from gateway.series import load_series

PROTO = ["--greenhouse", "biskra-prototype", "--model", "prototype"]


def _days(n_days: float, step: float = 300.0) -> np.ndarray:
    n = int(n_days * 86400 / step)
    return np.datetime64("2020-03-27T00:00:00", "s") + np.arange(n) * np.timedelta64(int(step), "s")


def _kit_csv(path, days: float):
    """A sunny box: radiation on a daily sine, the inside following it with a lag."""
    t = _days(days)
    hours = (t - t[0]).astype(float) / 3600.0
    sun = np.maximum(np.sin(2 * np.pi * (hours - 6.0) / 24.0), 0.0)
    rng = np.random.default_rng(3)
    cols = {"i_glob": np.round(800.0 * sun, 1),
            "t_out": np.round(15.0 + 6.0 * np.sin(2 * np.pi * (hours - 9.0) / 24.0), 1),
            "rh_out": np.full(len(t), 55.0), "wind": np.full(len(t), 1.5),
            "rh_in": np.full(len(t), 60.0)}
    cols["t_in"] = np.round(cols["t_out"] + 2.0 + 12.0 * np.roll(sun, 6)
                            + rng.normal(0.0, 0.1, len(t)), 1)
    return write_kit_csv(path, t, cols)


def test_the_note_counts_the_held_out_days():
    t = _days(10)
    assert short_heldout_note(t, len(t) // 2) is None  # 5 held-out days
    note = short_heldout_note(t, len(t) - int(2.5 * 86400 / 300))
    assert note is not None
    assert "only 2.5 days are held out" in note and f"{significance.MIN_DAYS} held-out days" in note


def test_diagnose_of_three_days_says_no_finding_can_come_out(capsys, tmp_path):
    data = _kit_csv(tmp_path / "three_days.csv", 3)
    assert main(["diagnose", "--data", str(data), *PROTO, "--step", "300"]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    assert "only 1.5 days are held out" in err and "no finding can be reported" in err
    assert "no finding can be reported" in out  # also beside the human report's figures


@pytest.mark.parametrize("step,split", [(60.0, 0.5), (300.0, 0.5), (300.0, 0.37), (900.0, 0.5)])
def test_the_split_said_before_the_run_is_the_diagnosis_own(tmp_path, step, split):
    """The note is made before the long run from ``search.split_index``: the row the diagnosis
    then reports as the start of its held-out part."""
    path = _kit_csv(tmp_path / "three_days.csv", 3)
    gh = load_greenhouse("biskra-prototype")
    model = build_model("prototype", gh)
    series = load_series(str(path), step=step, required=model.requires)
    d = diagnose(series, gh, model, split=split)
    assert split_index(series, split) == d.split_index

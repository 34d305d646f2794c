"""A stuck inside reading is counted in the data's own rows, not in grid samples
(gateway/estimate/sample_check.py ``stuck_limit``).

5-minute rows read to 0.1 °C (a DHT22 logger) replayed on the 60 s grid: still air (a heated
house held at its setpoint, a calm night) keeps the same reading for 7-12 rows, which the grid
repeats 30-60 times; counted in grid samples that was a stuck sensor, and up to 8 % of a
heated winter's readings were dropped. 30 identical rows in a row still are."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.estimate.online import online_settings
from gateway.estimate.replay import replay
from gateway.estimate.sample_check import STUCK_SAMPLES, stuck_limit
from gateway.greenhouse import load_greenhouse
from gateway.kitcsv import write_kit_csv
from gateway.model import build_model
from gateway.series import load_series

QUICK = {"t_in": {"iterations": 2, "bats": 4}}
"""The quickest swarm: the test is about which readings are dropped, not about the fit."""
ROW_S = 300


def test_the_limit_spans_thirty_of_the_datas_own_rows():
    assert stuck_limit(60.0) == stuck_limit(60.0, 60.0) == STUCK_SAMPLES
    assert stuck_limit(300.0, 300.0) == STUCK_SAMPLES  # the generality suite's replays
    assert stuck_limit(60.0, 300.0) == 29 * 5 + 1  # 30 rows 5 min apart on a 1-min grid
    assert stuck_limit(60.0, 30.0) == STUCK_SAMPLES  # finer rows are averaged onto the grid
    assert stuck_limit(60.0, 61.0) == STUCK_SAMPLES  # a slow clock: still 30


def _kit_rows(path, still: slice) -> None:
    """One day of 5-minute rows read to 0.1 °C, the inside reading held over ``still``."""
    rng = np.random.default_rng(4)
    n = 288
    t = np.datetime64("2020-03-27T00:00:00", "s") + np.arange(n) * np.timedelta64(ROW_S, "s")
    hour = np.arange(n) * ROW_S / 3600.0
    sun = np.clip(np.sin(np.pi * (hour - 6.0) / 12.0), 0.0, None)
    t_out = 12.0 + 6.0 * sun
    t_in = np.round(t_out + 2.0 + 8.0 * sun + rng.normal(0.0, 0.1, n), 1)
    t_in[still] = t_in[still.start]
    t_in[still.start - 1] = t_in[still.stop] = t_in[still.start] + 0.2  # the run is exactly that
    write_kit_csv(path, t, {"t_in": t_in, "rh_in": np.full(n, 70.0), "t_out": np.round(t_out, 1),
                            "rh_out": np.full(n, 60.0), "i_glob": np.round(600.0 * sun),
                            "wind": np.full(n, 1.5)})


@pytest.mark.parametrize(("rows", "stuck"), [(10, False), (40, True)])
def test_still_rows_are_kept_and_a_stuck_run_is_still_dropped(tmp_path, rows, stuck):
    gh = load_greenhouse("biskra-prototype")
    model = build_model("prototype", gh)
    _kit_rows(tmp_path / "kit.csv", slice(20, 20 + rows))  # a still night from 01:40
    series = load_series(str(tmp_path / "kit.csv"), step=60.0, required=model.requires)
    assert series.native_step == ROW_S
    repeats = (rows - 1) * 5 + 1  # what the grid holds of the run
    assert repeats > STUCK_SAMPLES  # counted in grid samples, both runs were stuck
    res = replay(model, series, gh, settings=online_settings(model, gh, QUICK), score=False)
    faults = res.counters.faults
    if not stuck:  # 10 rows (45 min) of one 0.1 °C reading: still air, every reading learnt
        assert "t_in:stuck" not in faults and "t_in:stuck_struck_out" not in faults
    else:  # 40 rows (3 h 15 min): stuck from the 30th row's sample on, the repeats before struck out
        limit = stuck_limit(60.0, ROW_S)
        assert faults["t_in:stuck"] == repeats - limit + 1
        assert faults["t_in:stuck_struck_out"] == limit - 2

"""Virtual ventilation sensor, the data side: the grower's vents, III.32, the input filter, the
training segments and the reference study."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.vsensor.features import (
    EXTRAS,
    columns_read,
    feature_names,
    filter_gains,
    flow_from_heat_loss,
    flux_names,
    heat_loss,
    low_pass,
    raw_features,
)
from tests import vsensor_data as vd
from training.simulate import PRESETS, simulate
from training.simulate.control import GrowerVents
from training.vsensor.dataset import build_segment


def test_grower_moves_vents_a_few_times_a_day_and_sometimes_forgets_them_at_night():
    plant = PRESETS["almeria"].with_(controller=GrowerVents(seed=7))
    r = simulate(plant, "almeria", "2020-06-01", 10, seed=1)
    roof, side = r.series["vent_roof"], r.series["vent_side"]
    moves = np.flatnonzero((np.diff(roof) != 0) | (np.diff(side) != 0))
    days = r.time[moves + 1].astype("datetime64[D]")
    per_day = np.unique(days, return_counts=True)[1]
    assert per_day.max() <= len(GrowerVents().visits)  # one move per visit at most
    hour = (r.time - r.time.astype("datetime64[D]")).astype(int) / 3600.0
    night_open = (hour > 1) & (hour < 5) & ((roof > 0) | (side > 0))
    nights = np.unique(r.time[night_open].astype("datetime64[D]"))
    assert 1 <= len(nights) < 10  # forgotten open some nights, not all
    again = simulate(plant, "almeria", "2020-06-01", 10, seed=1)
    assert np.array_equal(again.series["vent_roof"], roof)  # seeded


def test_iii32_round_trip_and_dead_band():
    gh = load_greenhouse(vd.GREENHOUSE)
    g = np.array([0.5, 3.0, 12.0, 2.0])
    dt = np.array([4.0, -3.0, 8.0, 0.1])
    back = flow_from_heat_loss(heat_loss(g, dt, gh), dt, gh)
    assert np.allclose(back[:3], g[:3])
    assert np.isnan(back[3])  # |ΔT| < 0.5 K: the heat loss says nothing about the flow
    # rho c_p G ΔT / A by hand
    assert heat_loss(3.0, 2.0, gh) == pytest.approx(1.2 * 1005.0 * 3.0 * 2.0 / 877.0)


def test_low_pass_holds_on_nan():
    raw = np.array([[1.0, np.nan], [np.nan, 2.0], [3.0, 4.0]])
    out = low_pass(raw, np.array([0.5, 1.0]))
    assert out[1, 0] == 1.0 and np.isnan(out[0, 1]) and out[2, 0] == 2.0 and out[2, 1] == 4.0


def test_the_inside_vapour_pressure_deficit_input_against_published_values():
    """``vpd_in`` (an extra input, kit columns only): FAO-56 Annex 2, Table 2.3, gives
    e°(25 °C) = 3.168 kPa and e°(10 °C) = 1.228 kPa, so at RH 50 % and 80 % the deficit is
    1.584 and 0.246 kPa; a missing RH gives NaN (flagged by the runtime, never a number)."""
    x = {"t_in": np.array([25.0, 10.0, 20.0]), "rh_in": np.array([50.0, 80.0, np.nan]),
         "t_out": np.zeros(3), "rh_out": np.full(3, 50.0), "wind": np.ones(3)}
    fluxes = {n: np.zeros(3) for n in feature_names("prototype")[3:]}
    raw = raw_features("prototype", x, fluxes, ("vpd_in",))
    assert feature_names("prototype", ("vpd_in",))[-1] == "vpd_in"
    np.testing.assert_allclose(raw[:2, -1], [1.584, 0.246], atol=2e-3)
    assert np.isnan(raw[2, -1])


@pytest.mark.parametrize("kind", ["almeria", "prototype"])
def test_the_columns_read_are_those_the_inputs_are_made_from(kind):
    """``columns_read`` (what vsensor checks the CSV for) against the code that makes the
    inputs: with a column all NaN, exactly the inputs it names are NaN, and every measured
    input is made from some column."""
    extra = tuple(EXTRAS)
    names = feature_names(kind, extra)
    x = {c: np.full(2, 20.0) for c in ("t_in", "t_out", "rh_in", "rh_out", "wind")}
    fluxes = {n: np.zeros(2) for n in flux_names(kind)}
    assert np.all(np.isfinite(raw_features(kind, x, fluxes, extra)))
    reads = columns_read(kind, extra)
    assert set(reads) == set(x)
    for col, inputs in reads.items():
        raw = raw_features(kind, {**x, col: np.full(2, np.nan)}, fluxes, extra)
        assert [n for j, n in enumerate(names) if np.isnan(raw[0, j])] == list(inputs)
    made = {n for inputs in reads.values() for n in inputs}
    assert made == set(names) - set(flux_names(kind))


def test_dataset_inputs_and_target():
    gh = load_greenhouse(vd.GREENHOUSE)
    seg = build_segment(vd.train_files()[0], gh, "almeria", vd.workdir() / "cache", vd.TINY)
    assert seg.inputs.shape == (len(seg.time), len(feature_names("almeria")))
    assert np.all(np.isnan(seg.flow[:60]))  # warm-up hour left out
    flow = seg.flow[60:]
    assert np.all(np.isfinite(flow)) and flow.min() >= 0.1 - 1e-9  # leakage c_loss >= 0.1
    truth_open = simulate(PRESETS["almeria"].with_(controller=GrowerVents(seed=3)), "almeria",
                          "2020-05-02", 1.5, seed=3).series["vent_roof"] > 0
    # the target is larger with the vents open than shut
    assert np.nanmean(seg.flow[truth_open]) > 2 * np.nanmean(seg.flow[~truth_open])
    assert np.allclose(seg.inputs, low_pass(seg.raw, filter_gains("almeria")), equal_nan=True)


def test_dataset_refuses_a_file_without_vents(tmp_path):
    gh = load_greenhouse(vd.GREENHOUSE)
    path = tmp_path / "novents.csv"
    lines = vd.test_file().read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if h not in ("vent_roof", "vent_side")]
    path.write_text("\n".join(",".join(row.split(",")[i] for i in keep) for row in lines) + "\n")
    with pytest.raises(ValueError, match="vent_roof or vent_side"):
        build_segment(path, gh, "almeria", None, vd.TINY)


def test_reference_study_describes_the_training_target_beside_the_truth(monkeypatch):
    from training.vsensor import reference
    from training.vsensor.reference import describe, study

    # Both studies below replay the same file with the same settings and seed; only ``above``
    # differs, and it is applied after the replay: the second study takes the first's replay.
    real, runs = reference.run_adaptive, []

    def replay_once(kind, series, gh, **kwargs):
        if not runs:
            runs.append((kind, series, kwargs, real(kind, series, gh, **kwargs)))
        assert kind == runs[0][0] and kwargs == runs[0][2]  # the same replay asked for
        np.testing.assert_array_equal(series.time, runs[0][1].time)
        return runs[0][3]

    monkeypatch.setattr(reference, "run_adaptive", replay_once)
    gh = load_greenhouse(vd.GREENHOUSE)
    path = vd.train_files()[0]
    seg = build_segment(path, gh, "almeria", vd.workdir() / "cache", vd.TINY)
    s = study(path, gh, "almeria", vd.TINY, above=0.0)
    flow = seg.flow[60:]
    # the very target the dataset holds (same replay, same seed)
    assert s.minutes == flow.size and s.explicit["max"] == pytest.approx(np.max(flow))
    assert s.explicit["mean"] == pytest.approx(np.mean(flow))
    assert s.truth is not None and s.truth["max"] > 0 and -1 <= s.r_truth <= 1  # the simulator's file
    assert s.peaks.minutes == s.minutes and s.peaks.truth_mean == pytest.approx(s.truth["mean"])
    assert 0.05 <= s.peaks.c_ven_d <= 1.0 and s.peaks.hours  # bounds of c_ven_d
    high = study(path, gh, "almeria", vd.TINY, above=1e6)
    assert high.peaks.minutes == 0 and high.peaks.truth_mean is None
    assert "peaks above" in describe(s) and "true flow" in describe(s)


def test_pca_variance_is_refused_below_the_issues_floor(tmp_path):
    from training.vsensor.train import train

    with pytest.raises(ValueError, match="pca_variance 0.8"):
        train([str(p) for p in vd.train_files()], load_greenhouse(vd.GREENHOUSE), "almeria",
              tmp_path / "m.onnx", vd.workdir() / "cache", vd.TINY, pca_variance=0.8)

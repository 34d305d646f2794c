"""Simulator outputs: determinism, kit CSV + truth round trip, CLI, weather sources, speed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gateway.kitcsv import read_kit_csv
from gateway.series import load_series
from training.__main__ import main
from training.simulate import load_truth, simulate
from training.simulate.plant import KIT_COLUMNS, PRO_COLUMNS
from training.simulate.solar import clear_sky_global, cos_zenith
from training.simulate.weather import bleiswijk, bleiswijk_range, synthetic


def test_determinism_per_seed():
    a = simulate("prototype", "biskra", "2019-01-26", days=1.0, seed=11)
    b = simulate("prototype", "biskra", "2019-01-26", days=1.0, seed=11)
    c = simulate("prototype", "biskra", "2019-01-26", days=1.0, seed=12)
    for name in a.columns:
        np.testing.assert_array_equal(a.columns[name], b.columns[name])
    assert not np.allclose(a.columns["t_out"], c.columns["t_out"], equal_nan=True)


def test_columns_per_plant_kind():
    proto = simulate("prototype", "biskra", "2019-01-26", days=0.5, seed=0)
    pro = simulate("almeria", "almeria", "2020-03-01", days=0.5, seed=0)
    assert tuple(proto.columns) == KIT_COLUMNS
    assert tuple(pro.columns) == PRO_COLUMNS
    assert set(proto.columns["rain"][np.isfinite(proto.columns["rain"])]) <= {0.0, 1.0}


def test_csv_and_truth_round_trip(tmp_path):
    r = simulate("almeria", "bleiswijk", "2009-11-01", days=1.0, seed=2,
                 effects=["cover_transmission@2009-11-01T10:40:factor=0.69",
                          "heater@2009-11-01T18:00:power=15,night_only=1"])
    csv_path, json_path, npz_path = r.write(tmp_path / "run.csv")
    assert json_path.name == "run.truth.json" and npz_path.name == "run.truth.npz"
    data = read_kit_csv(csv_path, required=("t_in", "t_out", "rh_in", "i_glob", "wind"))
    assert not data.notices
    np.testing.assert_array_equal(data.time, r.time)
    for name, values in r.columns.items():
        np.testing.assert_allclose(data.columns[name], values, rtol=1e-5, atol=1e-9,
                                   equal_nan=True)
    series = load_series(str(csv_path), step=60)
    assert len(series) == len(r.time)

    meta = json.loads(json_path.read_text())
    assert meta["csv"] == "run.csv" and meta["seed"] == 2 and meta["plant"] == "almeria"
    assert meta["weather"] == "bleiswijk"
    assert meta["effects"][0]["effect"] == "cover_transmission"
    assert meta["effects"][0]["start"] == "2009-11-01T10:40:00Z"
    assert meta["effects"][0]["params"] == {"factor": 0.69}
    truth = load_truth(json_path)
    np.testing.assert_array_equal(truth["time"], r.time)
    for name in ("g_vent", "q_vent", "q_conv_air_cover", "t_air"):
        assert truth["units"][name]["unit"]
        np.testing.assert_allclose(truth["series"][name], r.series[name], rtol=1e-6, atol=1e-6,
                                   equal_nan=True)


def test_cli_writes_files_and_rejects_bad_effects(tmp_path, capsys):
    out = tmp_path / "cli.csv"
    code = main(["simulate", "--plant", "prototype", "--weather", "biskra", "--days", "0.5",
                 "--seed", "1", "--effect", "sensor_drift@2019-01-26T06:00:rate=0.3",
                 "--out", str(out)])
    assert code == 0 and out.exists() and (tmp_path / "cli.truth.npz").exists()
    meta = json.loads((tmp_path / "cli.truth.json").read_text())
    assert meta["effects"][0]["params"] == {"rate": 0.3}
    code = main(["simulate", "--out", str(tmp_path / "x.csv"), "--effect", "door@2009-11-02"])
    err = capsys.readouterr().err
    assert code == 2 and "unknown effect 'door'" in err and "extra_leakage" in err
    assert not (tmp_path / "x.csv").exists()


def test_bleiswijk_weather_is_utc_and_consistent():
    first, last = bleiswijk_range()
    assert str(first) == "2009-10-19T23:00:00"
    w = bleiswijk(np.datetime64("2009-11-01"), 2.0)
    noon = w.time[np.argmax(w.i_glob[:1440])]
    hour = (noon - noon.astype("datetime64[D]")).astype(int) / 3600.0
    assert 10.5 < hour < 12.5  # solar noon at 4.5 degE is ~11:25 UTC in November
    assert np.all((w.rh_out > 0) & (w.rh_out <= 100))
    with pytest.raises(ValueError, match="covers"):
        bleiswijk(np.datetime64("2009-12-09"), 5.0)


def test_synthetic_weather_follows_solar_geometry():
    w = synthetic("biskra", np.datetime64("2019-06-01"), 10.0, seed=3)
    clear = clear_sky_global(cos_zenith(w.time, 34.722, 6.294))
    assert np.all(w.i_glob <= clear + 1e-9)
    assert np.all(w.i_glob[clear <= 0] == 0.0)
    daily_ratio = w.i_glob.reshape(10, -1).sum(1) / clear.reshape(10, -1).sum(1)
    assert daily_ratio.max() > 0.9  # clear days
    a = synthetic("almeria", np.datetime64("2020-01-10"), 3.0, seed=1)
    b = synthetic("almeria", np.datetime64("2020-01-10"), 3.0, seed=1)
    np.testing.assert_array_equal(a.t_out, b.t_out)
    assert w.t_out.mean() > a.t_out.mean() + 8.0  # Biskra June is far warmer than Almería Jan
    assert np.all(w.t_sky < w.t_out)


def test_fourteen_days_give_complete_minute_data():
    # Speed is measured in benches, never asserted in tests.
    r = simulate("almeria", "bleiswijk", "2009-11-01", days=14.0, seed=0)
    assert len(r.time) == 14 * 1440
    assert np.isfinite(r.columns["t_out"]).all() and np.isfinite(r.columns["t_soil"]).all()

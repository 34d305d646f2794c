"""Replay library and CLI: report shape, vectorised forecasts, files, errors, unseen-season figures."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from test_online import ALMERIA, FAST, GH, model_data

from gateway.cli import main
from gateway.cli.common import write_params_file
from gateway.estimate.online import online_settings
from gateway.estimate.replay import replay, report
from gateway.estimate.replay_forecasts import forecasts, forecasts_each
from gateway.kitcsv import write_kit_csv

METRIC_KEYS = {"mae", "rmse", "maxae", "r2", "ef", "n"}


@pytest.fixture(scope="module")
def drifting():
    """A day of the almeria model whose cover exchange and leakage drift by +60 % and c_tsw by
    -30 % over the day (dust, wear); the constant baseline keeps the starting values."""
    base = ALMERIA.defaults(GH)
    n = 24 * 60
    drift = np.ones(len(base))
    drift[ALMERIA.index("c_cnd_cnv")] = 1.6
    drift[ALMERIA.index("c_loss")] = 1.6
    drift[ALMERIA.index("c_tsw")] = 0.7
    series = model_data(ALMERIA, GH, hours=24, theta_at=lambda k: base * drift ** (k / n), seed=2)
    return series, base


DAY = {"t_in": {"iterations": 3, "bats": 10}, "i_in": {"iterations": 3, "bats": 10}}
"""The drifting day's budget (FAST's 8 iterations until 2026-11-28): the adaptive one-step MAE
0.181 of the constant's (0.179 with FAST), the radiation's 0.051 (the same), 1437 t_in and 35
i_in estimations (the same); the replay a third shorter."""


@pytest.fixture(scope="module")
def result(drifting):
    series, base = drifting
    return replay(ALMERIA, series, GH, base, online_settings(ALMERIA, GH, DAY), horizons=(15, 60))


def test_report_has_the_promised_shape_and_adaptation_pays(result):
    rep = report(result, warmup=60)
    assert rep["model"] == "almeria" and rep["samples"] == 1440 and rep["skipped"] == 0
    assert set(rep["metrics"]) == {"adaptive", "constant", "persistence", "arx"}
    for m in rep["metrics"].values():
        assert set(m) == METRIC_KEYS and m["n"] == rep["metrics"]["adaptive"]["n"]
    assert set(rep["horizons"]) == {"15", "60"}
    assert {"adaptive", "persistence"} <= set(rep["horizons"]["60"])
    assert set(rep["radiation"]) == {"adaptive", "constant"}
    assert set(rep["step_ms"]) == {"median", "p95", "max"} and rep["step_ms"]["median"] > 0
    one = rep["metrics"]
    assert one["adaptive"]["mae"] < 0.5 * one["constant"]["mae"]
    assert rep["radiation"]["adaptive"]["mae"] < 0.5 * rep["radiation"]["constant"]["mae"]
    assert rep["estimations"]["done"]["t_in"] > 1300 and rep["estimations"]["done"]["i_in"] > 10


def held_inside(x: dict, start: int) -> dict:
    """``x`` with the inside readings (and p_w,in) held at ``start`` from there on: the drivers
    of a forecast made at ``start`` with the weather later measured."""
    from gateway.estimate.horizon import INSIDE_READINGS

    out = {k: np.array(v, dtype=float) for k, v in x.items()}
    for k in INSIDE_READINGS:
        if k in out:
            out[k][start:] = out[k][start]
    return out


def test_forecasts_match_a_free_run_with_the_parameters_of_the_start(result):
    """A forecast is the free run from its start with the parameters in force then, the
    weather as later measured and the inside readings as at the start."""
    h = 15
    f = forecasts(result, h)
    for i in (100, 700, 1000):
        start = f["target"][i] - h
        x = held_inside(result.x, start)
        run = ALMERIA.free_run(result.theta[start][None, :], x, GH, 60.0, start, start + h + 1)
        assert f["adaptive"][i] == pytest.approx(run[0, -1], abs=1e-9)
        assert f["persistence"][i] == result.measured[start]
        # the inside humidity's later readings do not reach it (they would: q_trp, III.29)
        leaky = ALMERIA.free_run(result.theta[start][None, :], result.x, GH, 60.0, start,
                                 start + h + 1)
        assert abs(leaky[0, -1] - run[0, -1]) > 1e-6


def test_one_run_to_the_longest_horizon_reads_each_horizon_bit_for_bit(result):
    """Each kind run once to the longest horizon and read at the shorter ones on the way gives
    every horizon's own run exactly: the same keys in order, starts and values to the bit (90
    steps is past the outlook's 60: no outlook forecasts there, as alone)."""
    each = forecasts_each(result, [60, 15, 90, 30])
    for h in (15, 30, 60, 90):
        alone = forecasts(result, h)
        assert list(each[h]) == list(alone), h
        assert ("adaptive_outlook" in alone) == (h <= 60) and len(alone["target"]) > 1000
        for name, v in alone.items():
            np.testing.assert_array_equal(each[h][name], v, err_msg=f"{h} {name}", strict=True)


def test_replay_matches_the_sample_by_sample_estimator(drifting, result):
    """The replay library adds nothing: its predictions are the estimator's."""
    from gateway.estimate.online import OnlineEstimator

    series, base = drifting
    est = OnlineEstimator(ALMERIA, GH, base, online_settings(ALMERIA, GH, DAY), seed=0)
    preds = [est.update({k: float(v[t]) for k, v in series.columns.items()}).t_in for t in range(200)]
    np.testing.assert_array_equal(result.adaptive[1:201], np.array(preds, dtype=float))


@pytest.fixture(scope="module")
def files(tmp_path_factory, drifting):
    series, base = drifting
    d = tmp_path_factory.mktemp("replay")
    data = d / "day.csv"
    part = series.slice(0, 240)
    write_kit_csv(data, part.time, part.columns)
    params = d / "calibrated.toml"
    write_params_file(str(params), ALMERIA, dict(zip(ALMERIA.names, map(float, base), strict=True)), "test")
    return d, data, params


def test_cli_json_csv_and_plot(files, capsys):
    d, data, params = files
    out, png = d / "pred.csv", d / "replay.png"
    code = main(["replay", "--data", str(data), "--greenhouse", "almeria-palmerillas", "--model", "almeria",
                 "--params", str(params), "--json", "--out", str(out), "--plot", str(png),
                 "--set", "t_in.iterations=5", "--set", "t_in.bats=8", "--warmup", "30"])
    assert code == 0
    rep = json.loads(capsys.readouterr().out)
    assert {"model", "samples", "skipped", "metrics", "horizons", "radiation", "step_ms"} <= set(rep)
    assert set(rep["horizons"]) == {"15", "30", "60"}
    assert rep["settings"][0]["iterations"] == 5 and rep["start"] == "calibrated"
    with out.open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 240
    for col in ("time", "t_in_measured", "t_in_adaptive", "c_cnd_cnv", "c_tsw", "q_vent", "q_trp", "q_sol"):
        assert col in rows[0]
    assert png.stat().st_size > 20_000


def test_cli_replays_the_vented_prototype(files, capsys):
    """``--model prototype+vent_control``: the two vent-controller parameters are estimated
    and written beside the prototype's four."""
    d, data, _ = files
    out = d / "vented.csv"
    code = main(["replay", "--data", str(data), "--greenhouse", "almeria-palmerillas",
                 "--model", "prototype+vent_control", "--json", "--out", str(out),
                 "--set", "t_in.iterations=3", "--set", "t_in.bats=8"])
    assert code == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["model"] == "prototype+vent_control" and rep["samples"] == 240
    with out.open() as handle:
        row = next(csv.DictReader(handle))
    for col in ("c_solar", "c_loss", "c_vc", "t_vc", "q_vent_control"):
        assert col in row


def test_cli_human_output_without_calibration(files, capsys):
    d, data, _ = files
    code = main(["replay", "--data", str(data), "--greenhouse", "almeria-palmerillas", "--model", "almeria",
                 "--set", "t_in.iterations=3", "--set", "i_in.iterations=3"])
    assert code == 0
    text = capsys.readouterr().out
    assert "middle of the hard box" in text and "60-minute forecast" in text and "persistence" in text
    assert text.count("adaptive_kf") == 6  # with the measured weather and the outlook, 3 horizons
    assert text.count("combined") == 6


@pytest.mark.parametrize(
    "extra, message",
    [(["--set", "t_in.windw=3"], "unknown key 'windw'"), (["--set", "t_in.window"], "OUTPUT.KEY=NUMBER"),
     (["--set", "rh_in.window=3"], "no such estimation group"), (["--warmup", "1e6"], "leaves no sample"),
     (["--params", "/nonexistent.toml"], "cannot read parameters"),
     (["--warmup", "nan"], "--warmup must be")],
)
def test_cli_errors_are_one_clear_line(files, capsys, extra, message):
    _, data, _ = files
    code = main(["replay", "--data", str(data), "--greenhouse", "almeria-palmerillas", "--model", "almeria",
                 *extra])
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow
def test_unseen_season_adaptive_beats_constant_and_persistence(tmp_path):
    """Calibrate offline on simulated Bleiswijk autumn, replay a day of simulated Almería spring
    (another site, season and weather: data the fit never saw) with the thesis settings (reduced
    iteration count to keep the suite short)."""
    simulate = pytest.importorskip("training.simulate").simulate
    from gateway.estimate.calibrate import calibrate
    from gateway.estimate.swarm import make_algorithm
    from gateway.series import Series

    def series_of(r):
        return Series(r.time, 60.0, {k: np.asarray(v, float) for k, v in r.columns.items()})

    autumn = series_of(simulate(plant="almeria", weather="bleiswijk", start="2009-10-21", days=2, seed=0))
    spring = series_of(simulate(plant="almeria", weather="almeria", start="2020-03-27", days=1, seed=1))
    cal = calibrate(ALMERIA, autumn, GH, make_algorithm("rsba", "almeria", iterations=150), seed=0)
    # 4 t_in iterations (25 until 2026-11-28, then 12): adaptive MAE 0.0303 K (0.0299 at 12),
    # 0.21 of the constant's, 0.48 (0.49) of persistence's at 15 min; the replay ~40 % shorter
    # than at 12. Without the t_in estimation the adaptive run is the constant one: it fails.
    settings = online_settings(ALMERIA, GH, {"t_in": {"iterations": 4}})
    rep = report(replay(ALMERIA, spring, GH, cal.theta, settings), warmup=60)
    one = rep["metrics"]
    assert one["adaptive"]["mae"] <= 0.22
    assert one["adaptive"]["mae"] <= 0.5 * one["constant"]["mae"]
    for h in ("15", "30", "60"):
        block = rep["horizons"][h]
        assert block["adaptive"]["mae"] <= 0.7 * block["persistence"]["mae"], h


def test_a_record_shorter_than_the_horizons_replays_and_scores_none(drifting, tmp_path, capsys):
    """16 minutes (a short make run's export): the one-step figures, and no forecast scored at 30
    or 60 min, where the combination of the forecasts raised a ValueError before."""
    series, _ = drifting
    part, data = series.slice(0, 16), tmp_path / "short.csv"
    write_kit_csv(data, part.time, part.columns)
    code = main(["replay", "--data", str(data), "--greenhouse", "almeria-palmerillas", "--model",
                 "prototype", "--json", "--set", "t_in.iterations=3", "--set", "t_in.bats=8"])
    assert code == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["samples"] == 16 and rep["metrics"]["adaptive"]["n"] > 0
    for h in ("30", "60"):
        assert rep["horizons"][h]["combined"] is None and rep["horizons"][h]["persistence"] is None


def test_horizons_are_minutes_whatever_the_model_step(drifting):
    series, base = drifting
    coarse = series.slice(0, 360)
    coarse.time, coarse.step = coarse.time[::5], 300.0
    coarse.columns = {k: v[::5] for k, v in coarse.columns.items()}
    res = replay(ALMERIA, coarse, GH, base, online_settings(ALMERIA, GH, FAST), horizons=(15, 60, 7))
    assert set(res.horizons) == {15, 60}  # 7 min is not a whole number of 5-minute steps
    f = res.horizons[15]
    assert np.all(f["measured"] == res.measured[f["target"]])
    assert np.all(f["persistence"] == res.measured[f["target"] - 3])
    assert set(report(res)["horizons"]) == {"15", "60"}


def test_report_has_the_arx_baseline_and_the_outlook_forecasts(result):
    rep = report(result, warmup=60)
    assert rep["outlook"] == "clear-sky-trend"  # the preset has a [site]
    assert "arx" in rep["metrics"]
    for block in rep["horizons"].values():
        assert {"adaptive", "adaptive_kf", "combined", "corrected", "constant", "arx",
                "persistence", "adaptive_outlook", "adaptive_kf_outlook", "combined_outlook",
                "corrected_outlook", "arx_outlook"} == set(block)
        assert len({m["n"] for m in block.values()}) == 1  # one set of samples per comparison


KIT = ["t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "i_in", "t_soil", "vent_roof",
       "vent_side", "lai"]
"""The almeria model's columns, the kit's and the house's: what an outlook is asked for."""


class MeasuredFuture:
    """An outlook that returns the weather later measured, the inside readings held at the
    start, as a model-skill forecast reads them (to check the blocks' layout)."""

    name = "measured"

    def drivers_at(self, columns, time, starts, horizon, dt):
        from gateway.estimate.horizon import INSIDE_READINGS

        idx = np.minimum(starts[:, None] + np.arange(1, horizon + 1)[None, :], len(time) - 1)
        held = np.repeat(starts[:, None], horizon, axis=1)
        return {k: np.asarray(v, float)[held if k in INSIDE_READINGS else idx]
                for k, v in columns.items()}


def steady_sky(result):
    """``result`` with one cloud fraction all along (its sky temperature made from it): an
    outlook holds the start's cloud over its horizon (gateway/estimate/horizon.py), so only
    where the cloud does not move can the outlook's blocks equal the measured future."""
    from dataclasses import replace as copy_with

    from gateway.model import sky

    x = dict(result.x)
    x["cloud"] = np.full(len(result.time), 0.4)
    x["t_sky"] = sky.sky_temperature(x["t_out"], x.get("rh_out"), x["cloud"])
    return copy_with(result, x=x)


def test_an_outlook_of_the_measured_future_gives_the_measured_weather_forecasts(result):
    """The driver blocks (gateway/estimate/horizon.py) are laid out right: an outlook that
    returns what was later measured reproduces the measured-weather forecasts exactly (under a
    steady sky: the outlook holds the start's cloud)."""
    from dataclasses import replace as copy_with

    from gateway.estimate.horizon import outlook_drivers

    n = len(result.measured)
    steady = steady_sky(result)
    ahead = outlook_drivers(MeasuredFuture(), steady.x, KIT, result.time, result.dt, result.gh,
                            np.arange(n - 1), 15)
    f = forecasts(copy_with(steady, ahead=ahead), 15)
    ok = np.isfinite(f["adaptive"])
    assert ok.sum() > 1000
    np.testing.assert_allclose(f["adaptive_outlook"][ok], f["adaptive"][ok], atol=1e-9)
    np.testing.assert_allclose(f["arx_outlook"][ok], f["arx"][ok], atol=1e-9)
    np.testing.assert_allclose(f["adaptive_kf_outlook"][ok], f["adaptive_kf"][ok], atol=1e-9)
    np.testing.assert_allclose(f["combined_outlook"][ok], f["combined"][ok], atol=1e-9)


def test_the_outlook_correction_reads_the_outlook_blocks(result, monkeypatch):
    """The error correction's change of the weather over the horizon comes from the forecast's
    own drivers: with an outlook of the measured future, ``corrected_outlook`` is ``corrected``
    (the correction applied from an hour on: the series has no day to learn from)."""
    from dataclasses import replace as copy_with

    from gateway.estimate import correction
    from gateway.estimate.horizon import outlook_drivers
    from gateway.estimate.replay import score_forecasts, steps_of

    class Quick(correction.Corrector):
        def __init__(self, horizons, dt, *args) -> None:
            super().__init__(horizons, dt, correction.MEMORY_S, correction.RIDGE, 3600.0)

    monkeypatch.setattr(correction, "Corrector", Quick)
    n = len(result.measured)
    reach = steps_of((15, 60), result.dt)
    steady = steady_sky(result)
    ahead = outlook_drivers(MeasuredFuture(), steady.x, KIT, result.time, result.dt, result.gh,
                            np.arange(n - 1), max(reach.values()))
    res = copy_with(steady, ahead=ahead, horizons={})
    score_forecasts(res, reach)
    for f in res.horizons.values():
        ok = np.isfinite(f["corrected"]) & np.isfinite(f["corrected_outlook"])
        assert ok.sum() > 1000
        assert np.mean(np.abs(f["corrected"][ok] - f["combined"][ok]) > 1e-3) > 0.5
        np.testing.assert_allclose(f["corrected_outlook"][ok], f["corrected"][ok], atol=1e-9)

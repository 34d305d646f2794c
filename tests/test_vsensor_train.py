"""Training side of the virtual ventilation sensor: held-out scores, reproducibility, ensembles,
feedback rounds, tuning, extra features and members on their own feedback."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.vsensor.features import INPUT_DELAYS, feature_names
from tests import vsensor_data as vd
from training.vsensor.dataset import build_segment


def test_held_out_score_is_what_the_gateway_cli_reports():
    """``train --test`` scores from the cached replays exactly as ``python -m gateway vsensor``
    (its JSON report: the main sensor's figures, the baselines' beside them)."""
    from gateway.vsensor.batch import baseline_paths
    from training.vsensor.heldout import score_segment, table

    gh = load_greenhouse(vd.GREENHOUSE)
    model = vd.tiny_model()
    seg = build_segment(vd.test_file(), gh, "almeria", vd.workdir() / "cache", vd.TINY)
    ours = score_segment(seg, {"pca_narx": model, **baseline_paths(model)}, gh, "almeria")
    code, report, _ = vd.cli_run(model)  # the CLI's run, shared with test_vsensor_runtime
    assert code == 0
    cli = {"pca_narx": report, **report["baselines"]}
    assert set(ours) == set(cli) == {"pca_narx", "narx_no_pca", "linear_arx"}
    for name in cli:
        assert ours[name]["flow"]["mae"] == pytest.approx(cli[name]["flow"]["mae"], rel=1e-9)
        assert ours[name]["q_vent"]["rmse"] == pytest.approx(cli[name]["q_vent"]["rmse"], rel=1e-9)
        assert ours[name]["out_of_range"] == cli[name]["out_of_range"]
    assert "| test-grower, range" in table({"test-grower": ours})


def test_training_is_seeded_and_byte_reproducible():
    a, b = vd.tiny_model("a"), vd.tiny_model("b")
    assert a.read_bytes() == b.read_bytes()
    for base in ("narx_no_pca", "linear_arx"):
        assert a.with_name(f"tiny.{base}.onnx").read_bytes() == b.with_name(f"tiny.{base}.onnx").read_bytes()


def test_ensemble_training_is_reproducible_and_runs_in_the_gateway():
    import json

    from gateway.vsensor import VentSensor

    a, b = vd.tiny_model("ens-a", ensemble=2), vd.tiny_model("ens-b", ensemble=2)
    assert a.read_bytes() == b.read_bytes()
    meta = {p.key: p.value for p in onnx.load(str(a)).metadata_props}
    assert json.loads(meta["training_settings"])["ensemble"] == 2
    log = json.loads(meta["metrics"])["training_log"]["pca_narx"]
    assert log["seeds"] == [0, 1] and len(log["ensemble_val_mae_by_size"]) == 2
    single = vd.tiny_model()
    # member 0 is the single network of the same seed, so one member is its figure
    single_log = json.loads({p.key: p.value for p in onnx.load(str(single)).metadata_props}["metrics"])
    assert log["ensemble_val_mae_by_size"][0] == pytest.approx(
        single_log["validation_closed_loop"]["pca_narx"]["mae"], rel=1e-9)
    assert "--ensemble 2" in a.with_suffix(".md").read_text()
    sensor = VentSensor(a, load_greenhouse(vd.GREENHOUSE), "almeria")
    est = sensor.step({"t_in": 24.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 55.0, "wind": 3.0},
                      dict.fromkeys(feature_names("almeria")[3:], 0.0))
    assert np.isfinite(est.flow) and est.flow >= 0


def test_prototype_kind_trains_and_runs(tmp_path):
    """The kit's own model: fluxes of the prototype model, the Kittas vent term added in its
    units for the explicit estimate, the prototype's q_loss as the leakage."""
    from threadpoolctl import threadpool_limits

    from gateway.series import load_series
    from gateway.vsensor import VentSensor
    from gateway.vsensor.adaptive import run_adaptive
    from gateway.vsensor.batch import run_sensor
    from training.vsensor.train import train

    gh = load_greenhouse(vd.GREENHOUSE)
    seg = build_segment(vd.train_files()[0], gh, "prototype", vd.workdir() / "cache", vd.TINY)
    assert seg.inputs.shape[1] == len(feature_names("prototype")) == 7
    flow = seg.flow[60:]
    assert np.all(np.isfinite(flow)) and flow.min() > 0
    out = tmp_path / "proto.onnx"
    with threadpool_limits(1):
        train([str(vd.train_files()[0])], gh, "prototype", out, vd.workdir() / "cache", vd.TINY,
              hidden=(6,), epochs=3, rounds=0)
    novent = run_adaptive("prototype", load_series(str(vd.test_file())), gh, False, vd.TINY)
    run = run_sensor(VentSensor(out, gh, "prototype"), novent)
    assert np.all(np.isfinite(run.flow)) and run.flow.min() >= 0


def test_feedback_noise_offsets_only_the_past_outputs_seeded_and_never_below_zero_flow():
    from training.vsensor.fit import feedback_noise

    assert feedback_noise(0.0, -1.0, np.random.default_rng(0)) is None
    h = np.zeros((2000, 12))
    a = feedback_noise(0.5, -0.3, np.random.default_rng(4))(h)
    b = feedback_noise(0.5, -0.3, np.random.default_rng(4))(h)
    assert np.array_equal(a, b) and np.all(h == 0)  # seeded, the rows themselves untouched
    assert np.all(a[:, :-5] == 0)  # the inputs' columns are not touched
    past = a[:, -5:]
    assert np.all(past == past[:, :1])  # one common offset per row over the five delays
    assert past.min() == pytest.approx(-0.3)  # clipped at the scaled zero flow
    above = past[:, 0][past[:, 0] > 0]
    assert 0.35 < np.sqrt(np.mean(above ** 2)) < 0.65  # the positive half of N(0, 0.5)


def test_high_flow_rows_weigh_more_with_a_mean_weight_of_one():
    from training.vsensor.fit import RowOptions, row_weights

    t = np.arange(10.0)
    assert row_weights(t, 7.5, 1.0) is None
    w = row_weights(t, 7.5, 4.0)
    assert w.mean() == pytest.approx(1.0) and w[9] == pytest.approx(4 * w[0])
    assert np.all(w[:8] == w[0]) and np.all(w[8:] == w[9])
    assert RowOptions().as_settings() == {}  # the defaults leave the model's settings unchanged
    assert RowOptions(0.1, 2.0).as_settings() == {"feedback_noise": 0.1, "high_flow_weight": 2.0}


def test_rounds_on_the_ensemble_feedback_are_seeded_and_logged(tmp_path):
    import json

    from threadpoolctl import threadpool_limits

    from training.vsensor.train import train

    gh = load_greenhouse(vd.GREENHOUSE)
    paths = [str(p) for p in vd.train_files()]
    out = []
    for tag in ("a", "b"):
        with threadpool_limits(1):
            r = train(paths, gh, "almeria", tmp_path / tag / "m.onnx", vd.workdir() / "cache",
                      vd.TINY, hidden=(8, 8), epochs=8, rounds=2, ensemble=2,
                      feedback="ensemble", feedback_noise=0.2, high_flow_weight=3.0)
        out.append(r)
    assert out[0].paths["pca_narx"].read_bytes() == out[1].paths["pca_narx"].read_bytes()
    log = out[0].logs["pca_narx"]
    assert log["feedback"] == "ensemble" and len(log["ensemble_round_val_mae"]) == 3
    # the kept round's ensemble is the model: its figure is the validation metric
    assert min(log["ensemble_round_val_mae"]) == pytest.approx(out[0].metrics["pca_narx"]["mae"])
    assert log["ensemble_val_mae_by_size"][-1] == pytest.approx(out[0].metrics["pca_narx"]["mae"])
    meta = {p.key: p.value for p in onnx.load(str(out[0].paths["pca_narx"])).metadata_props}
    st = json.loads(meta["training_settings"])
    assert st["feedback"] == "ensemble" and st["feedback_noise"] == 0.2
    assert st["high_flow_weight"] == 3.0
    card = out[0].card.read_text()
    assert "--feedback ensemble --feedback-noise 0.2 --high-flow-weight 3" in card
    with pytest.raises(ValueError, match="feedback 'own'"):
        train(paths, gh, "almeria", tmp_path / "c.onnx", vd.workdir() / "cache", vd.TINY,
              hidden=(8,), epochs=1, rounds=1, ensemble=2, feedback="own")


def test_tune_prints_the_pca_narx_train_would_fit(tmp_path, capsys):
    import json

    from training.vsensor.cli import main

    paths = [str(p) for p in vd.train_files()]
    log = tmp_path / "tune.jsonl"
    args = ["--data", *paths, "--greenhouse", vd.GREENHOUSE, "--model", "almeria",
            "--cache", str(vd.workdir() / "cache"),
            *[a for part, opts in vd.TINY.items() for k, v in opts.items()
              for a in ("--set", f"{part}.{k}={v}")],  # the budget of the tiny sensors' replays
            "--hidden", "8,8", "--epochs", "8", "--rounds", "1"]
    capsys.readouterr()
    assert main(["tune", *args, "--subset", "train-grower", "--log", str(log)]) == 0
    out, err = capsys.readouterr()  # stdout the summary alone, the progress on stderr
    assert json.loads(out)["label"] == "" and err.splitlines()[-1].startswith("progress: tune done")
    got = json.loads(log.read_text())
    model = tmp_path / "m.onnx"
    assert main(["train", *args, "--out", str(model)]) == 0
    out, err = capsys.readouterr()  # stderr not a terminal: the log's progress lines
    # the total is an upper bound (early stopping, cached replays): the done line ends the log
    assert "progress: train 10 %" in err, err
    assert err.splitlines()[-1].startswith("progress: train done, "), err
    assert "progress" not in out and "\x1b" not in err and "\r" not in err
    meta = {p.key: p.value for p in onnx.load(str(model)).metadata_props}
    trained = json.loads(meta["metrics"])["validation_closed_loop"]["pca_narx"]
    assert got["mae"] == pytest.approx(trained["mae"], rel=1e-12)
    assert got["groups"]["grower"] == pytest.approx(trained["by_file"]["train-grower"]["mae"])
    assert got["groups"]["controller"] == pytest.approx(trained["by_file"]["train-controller"]["mae"])
    assert got["groups"]["subset"] == got["groups"]["grower"]
    capsys.readouterr()
    assert main(["errors", "--sensor", str(model), *args[:-6]]) == 0
    text = capsys.readouterr().out
    assert "by file:" in text and "by vents:" in text and "train-grower" in text
    shares = [float(line.split()[-2].rstrip("%")) for line in text.splitlines()[2:4]]
    assert sum(shares) == pytest.approx(100.0, abs=0.2)  # the two files share all the error


def test_extra_features_and_sqrt_target_run_the_same_live_as_in_training(tmp_path):
    """A model trained on √G with the derived inputs: the gateway's VentSensor (its own feature
    code, minute by minute) gives the flows of the batch closed loop on training's features,
    and its metadata names what it was trained with."""
    import json

    from threadpoolctl import threadpool_limits

    from gateway.vsensor import VentSensor
    from training.vsensor.train import train

    gh = load_greenhouse(vd.GREENHOUSE)
    extra = ("dvp_in_out", "wind_dt")
    with threadpool_limits(1):
        r = train([str(p) for p in vd.train_files()], gh, "almeria", tmp_path / "m.onnx",
                  vd.workdir() / "cache", vd.TINY, hidden=(8, 8), epochs=8, rounds=1,
                  target="sqrt", extra_features=extra)
    model = r.paths["pca_narx"]
    meta = {p.key: p.value for p in onnx.load(str(model)).metadata_props}
    names = [f["name"] for f in json.loads(meta["features"])]
    assert names == [*feature_names("almeria"), *extra]
    st = json.loads(meta["training_settings"])
    assert st["target_transform"] == "sqrt" and st["extra_features"] == list(extra)
    assert "--target sqrt --extra-features dvp_in_out wind_dt" in r.card.read_text()
    seg = build_segment(vd.test_file(), gh, "almeria", vd.workdir() / "cache", vd.TINY, extra=extra)
    assert seg.inputs.shape[1] == len(names)
    _, live, batch = vd.live_and_batch(model, gh, extra)
    assert np.allclose(live, batch, rtol=1e-4, atol=1e-4)
    assert np.all(live >= 0)
    # the model without its extras' code is refused, naming the input
    from gateway.vsensor.model_info import ModelInfo, ModelMismatch, check_model

    info = VentSensor(model, gh, "almeria").info
    renamed = ModelInfo(**{**info.__dict__, "names": (*info.names[:-1], "no_such_input")})
    with pytest.raises(ModelMismatch, match="no_such_input"):
        check_model(renamed, "almeria")


def test_members_on_their_own_feedback_are_k_loops_averaged():
    """``fit.simulate_own_feedback``: two identical members hear the same past either way; two
    different ones give the mean of their single closed loops."""
    from training.vsensor import fit
    from training.vsensor.narx import Layer, Narx
    from training.vsensor.train import prepare

    gh = load_greenhouse(vd.GREENHOUSE)
    prep = prepare([str(p) for p in vd.train_files()], gh, "almeria", vd.workdir() / "cache",
                   vd.TINY, 0, 0.95, lambda **k: None)
    rng = np.random.default_rng(3)
    width = len(INPUT_DELAYS) * prep.loadings.shape[1] + 5

    def stack():
        return [Layer(0.1 * rng.normal(size=(width, 4)), rng.normal(size=4), "tanh"),
                Layer(rng.normal(size=(4, 1)), rng.normal(size=1), "identity")]

    a, b = stack(), stack()
    args = ("pca_narx", prep.mean, prep.std, prep.loadings, 2.0, 3.0)
    same = Narx(*args, a, members=[a, a])
    for x, y in zip(fit.simulate_own_feedback(same, prep.split), fit.simulate(same, prep.split),
                    strict=True):
        assert np.allclose(x, y)
    two = Narx(*args, a, members=[a, b])
    singles = [fit.simulate(Narx(*args, s), prep.split) for s in (a, b)]
    own = fit.simulate_own_feedback(two, prep.split)
    for i, y in enumerate(own):
        assert np.allclose(y, (singles[0][i] + singles[1][i]) / 2)


def test_members_on_their_own_past_run_the_same_live_as_in_training(tmp_path):
    """``--own-feedback``: the graph takes K output histories and gives K flows; the gateway's
    VentSensor (minute by minute) gives the batch closed loop's flows, and the validation figure
    is that of K loops averaged."""
    import json

    from threadpoolctl import threadpool_limits

    from training.vsensor.train import train

    gh = load_greenhouse(vd.GREENHOUSE)
    with threadpool_limits(1):
        r = train([str(p) for p in vd.train_files()], gh, "almeria", tmp_path / "m.onnx",
                  vd.workdir() / "cache", vd.TINY, hidden=(8, 8), epochs=8, rounds=1,
                  ensemble=2, own_feedback=True, target="log1p")
    model = r.paths["pca_narx"]
    meta = {p.key: p.value for p in onnx.load(str(model)).metadata_props}
    assert json.loads(meta["feedback_histories"]) == 2
    assert json.loads(meta["training_settings"])["own_feedback"] is True
    assert "--ensemble 2 --target log1p --own-feedback" in r.card.read_text()
    sess = ort.InferenceSession(str(model), providers=["CPUExecutionProvider"])
    assert sess.get_inputs()[1].shape[1:] == [2, 5] and sess.get_outputs()[0].shape[1] == 2
    sensor, live, batch = vd.live_and_batch(model, gh)
    assert sensor.histories == 2
    assert np.allclose(live, batch, rtol=1e-4, atol=1e-4)
    # the train log's shared-feedback ensemble differs from the shipped own-feedback figure
    log = r.logs["pca_narx"]
    assert r.metrics["pca_narx"]["mae"] != pytest.approx(log["ensemble_val_mae_by_size"][-1], rel=1e-9)

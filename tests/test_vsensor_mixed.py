"""The mixed ensemble (docs/vsensor.md, ninth pass, ``--target mixed``): even seeds learn the
flow, odd seeds the effective opening, each member fitted as in its one-target ensemble, the
members averaged as flows in one graph; the metadata names the members' targets and the runtime
refuses what it cannot serve."""

from __future__ import annotations

import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.vsensor import ModelMismatch, VentSensor
from tests import vsensor_data as vd
from training.vsensor.export import write_model
from training.vsensor.narx import Driver, Layer, MixedNarx, Narx, member_target


@pytest.fixture(scope="module")
def gh():
    return load_greenhouse(vd.GREENHOUSE)


@pytest.fixture(scope="module")
def mixed_model():
    return vd.tiny_model("mixed-a", ensemble=2, target="mixed")


def _stack(rng, n_in: int) -> list[Layer]:
    return [Layer(rng.normal(size=(n_in, 8)), rng.normal(size=8), "tanh"),
            Layer(rng.normal(size=(8, 1)), rng.normal(size=1), "identity")]


def _inputs(rng, n: int, f: int) -> np.ndarray:
    u = rng.normal(size=(n, 6, f))
    u[..., 0] = rng.uniform(0.0, 8.0, (n, 6))  # wind [m s-1]
    u[..., 1] = rng.uniform(-3.0, 8.0, (n, 6))  # T_in - T_out [K]
    u[:3, :, :2] = 0.0  # still air at the outside temperature: the driver's floor
    return u


def _run(path, u, yp) -> np.ndarray:
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return sess.run(None, {"u": u.astype(np.float32), "y_past": yp.astype(np.float32)})[0]


@pytest.mark.parametrize("own", [False, True])
def test_graph_is_the_members_flows_averaged(gh, own):
    """Three members (flow, opening, flow) with their own output scalings: the graph gives the
    mean of the members' own flows (each member a one-target network: Narx.predict, whose graphs
    the export and opening tests hold), or every member's flow on its own past."""
    rng = np.random.default_rng(11)
    f, n = 8, 40
    pre = (rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, 3)))
    drv = Driver.of_greenhouse(gh)
    parts = [Narx("pca_narx", *pre, 2.0, 1.5, _stack(rng, 23)),
             Narx("pca_narx", *pre, 0.05, 0.04, _stack(rng, 23), target="opening", driver=drv,
                  flow_median=2.0),
             Narx("pca_narx", *pre, 2.0, 1.5, _stack(rng, 23))]
    net = MixedNarx("pca_narx", parts, own_feedback=own)
    assert net.targets == ["flow", "opening", "flow"] and net.y0 == 2.0
    path = vd.workdir() / f"mixed-{own}.onnx"
    write_model(net, f, {"model_kind": "almeria"}, path)
    u = _inputs(rng, n, f)
    yp = rng.uniform(0.0, 9.0, size=(n, 3, 5) if own else (n, 5))
    if own:
        want = np.column_stack([p.predict(u, yp[:, j]) for j, p in enumerate(parts)])
    else:
        want = np.mean([p.predict(u, yp) for p in parts], axis=0)[:, None]
    got = _run(path, u, yp)
    assert got.shape == want.shape
    assert np.allclose(got, want, rtol=1e-4, atol=1e-4)
    assert np.allclose(net.predict(u, yp).reshape(want.shape), want, rtol=1e-12, atol=1e-12)


def test_members_of_one_target_are_the_one_target_ensemble(gh):
    """Averaging flows is what an ensemble of one target does: two flow members sharing their
    scaling give the ``--ensemble 2`` graph's flow."""
    rng = np.random.default_rng(12)
    f, n = 8, 30
    pre = (rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, 3)), 2.0, 1.5)
    a, b = _stack(rng, 23), _stack(rng, 23)
    mixed = MixedNarx("pca_narx", [Narx("pca_narx", *pre, a), Narx("pca_narx", *pre, b)])
    plain = Narx("pca_narx", *pre, a, members=[a, b])
    write_model(mixed, f, {"model_kind": "almeria"}, vd.workdir() / "two-flows.onnx")
    u, yp = _inputs(rng, n, f), rng.uniform(0.0, 9.0, size=(n, 5))
    assert np.allclose(_run(vd.workdir() / "two-flows.onnx", u, yp)[:, 0], plain.predict(u, yp),
                       rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="single networks"):
        MixedNarx("pca_narx", [plain, plain])


def test_members_are_fitted_as_in_their_one_target_ensembles(gh):
    """Member 0 (even seed) is the flow ensemble's member 0 and member 1 (odd seed) the opening
    ensemble's member 1, weight for weight."""
    from training.vsensor import fit
    from training.vsensor.train import prepare

    prep = prepare([str(p) for p in vd.train_files()], gh, "almeria", vd.workdir() / "cache",
                   vd.TINY, 0, 0.95, lambda **k: None)
    args = ("pca_narx", prep.split, prep.mean, prep.std, prep.loadings, [0, 1], (8, 8), 6, 1, 6)

    def ens(target: str):
        return fit.fit_ensemble(*args, opts=fit.row_options(0.1, 1.0, target, gh))

    mixed, log = ens("mixed")
    assert [member_target(s) for s in (0, 1, 2, 3)] == ["identity", "opening"] * 2
    assert log["targets"] == ["identity", "opening"] and mixed.targets == ["flow", "opening"]
    for j, target in ((0, "identity"), (1, "opening")):
        one = ens(target)[0]
        assert mixed.parts[j].target == target
        for got, want in zip(mixed.parts[j].layers, one.members[j], strict=True):
            assert np.array_equal(got.weight, want.weight) and np.array_equal(got.bias, want.bias)
    assert log["ensemble_val_mae_by_size"][-1] == pytest.approx(fit.validation_mae(mixed, prep.split))


def test_mixed_model_is_reproducible_named_and_runs_live_as_in_training(gh, mixed_model):
    assert mixed_model.read_bytes() == vd.tiny_model("mixed-b", ensemble=2, target="mixed").read_bytes()
    meta = {p.key: p.value for p in onnx.load(str(mixed_model)).metadata_props}
    assert meta["target_kind"] == "mixed"
    assert json.loads(meta["member_targets"]) == ["flow", "opening"]
    assert json.loads(meta["opening_driver"]) == Driver.of_greenhouse(gh).as_meta()
    assert json.loads(meta["training_settings"])["target_transform"] == "mixed"
    card = mixed_model.with_suffix(".md").read_text()
    assert "--ensemble 2 --target mixed" in card and "odd seeds' the effective opening" in card
    linear = {p.key: p.value for p in onnx.load(str(mixed_model.with_name(
        "tiny.linear_arx.onnx"))).metadata_props}
    assert "target_kind" not in linear  # the linear ARX stays on the flow
    sensor, live, batch = vd.live_and_batch(mixed_model, gh)
    assert sensor.histories == 1
    assert np.allclose(live, batch, rtol=1e-4, atol=1e-4)
    assert np.all(np.isfinite(live)) and live.min() >= 0.0


def test_the_runtime_refuses_a_mixed_model_it_cannot_serve(gh, mixed_model, tmp_path):
    meta = {p.key: p.value for p in onnx.load(str(mixed_model)).metadata_props}
    drv = json.loads(meta["opening_driver"])
    cases = [({"member_targets": None}, "without its members' targets"),
             ({"member_targets": ["flow"]}, "without its members' targets"),
             ({"member_targets": ["flow", "velocity"]}, "member target velocity"),
             ({"feedback_histories": 3}, "2 member targets for 3 output histories"),
             ({"opening_driver": None}, "without its driver"),
             ({"opening_driver": {**drv, "w": drv["w"] * 1.01}}, "opening driver w")]
    for i, (changes, message) in enumerate(cases):
        with pytest.raises(ModelMismatch, match=message):
            VentSensor(vd.rewrite_metadata(mixed_model, tmp_path / f"bad{i}.onnx", **changes), gh, "almeria")
    flow_as_mixed = vd.rewrite_metadata(vd.tiny_model(), tmp_path / "flow.onnx", target_kind="mixed")
    with pytest.raises(ModelMismatch, match="without its members' targets"):
        VentSensor(flow_as_mixed, gh, "almeria")


def test_cli_refuses_a_mixed_target_it_cannot_fit_before_any_replay(tmp_path, capsys):
    from training.vsensor.cli import main

    base = ["--data", str(tmp_path / "absent.csv"), "--greenhouse", vd.GREENHOUSE, "--model",
            "almeria", "--target", "mixed"]
    assert main(["tune", *base, "--ensemble", "1"]) == 2
    assert "at least 2 networks" in capsys.readouterr().err
    assert main(["train", *base, "--ensemble", "2", "--feedback", "ensemble", "--out",
                 str(tmp_path / "m.onnx")]) == 2
    assert "fits its members apart" in capsys.readouterr().err

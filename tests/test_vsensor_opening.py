"""The effective-opening target (docs/vsensor.md, eighth pass): the network learns G / D, the
graph computes the ventilation driver D from its inputs and multiplies it back, so flows go in
and come out; the metadata names the target kind and the runtime refuses a mismatch."""

from __future__ import annotations

import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.model.almeria import ventilation_driver
from gateway.vsensor import ModelMismatch, VentSensor
from gateway.vsensor.features import feature_names
from tests import vsensor_data as vd
from training.vsensor.export import write_model
from training.vsensor.narx import T_OUT_REF, Driver, Layer, Narx


@pytest.fixture(scope="module")
def gh():
    return load_greenhouse(vd.GREENHOUSE)


@pytest.fixture(scope="module")
def opening_model():
    return vd.tiny_model("opening-a", ensemble=2, target="opening")


def _inputs(rng, n: int, f: int) -> np.ndarray:
    """Random standardised-looking inputs with a plausible wind (0–8 m s-1) and ΔT (−3…8 K)."""
    u = rng.normal(size=(n, 6, f))
    u[..., 0] = rng.uniform(0.0, 8.0, (n, 6))
    u[..., 1] = rng.uniform(-3.0, 8.0, (n, 6))
    u[:3, :, :2] = 0.0  # still air, no ΔT: the driver's floor
    return u


@pytest.mark.parametrize("own", [False, True])
def test_graph_flow_is_the_opening_times_the_model_layers_driver(gh, own):
    rng = np.random.default_rng(7)
    f, n = 8, 30
    members = [[Layer(rng.normal(size=(23, 8)), rng.normal(size=8), "tanh"),
                Layer(rng.normal(size=(8, 1)), rng.normal(size=1), "identity")] for _ in range(2)]
    drv = Driver.of_greenhouse(gh)
    args = ("pca_narx", rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, 3)), 0.05, 0.04)
    net = Narx(*args, members[0], members=members, target="opening", driver=drv, flow_median=1.5,
               own_feedback=own)
    path = vd.workdir() / f"opening-{own}.onnx"
    write_model(net, f, {"model_kind": "almeria"}, path)
    u = _inputs(rng, n, f)
    yp = rng.uniform(0.0, 9.0, size=(n, 2, 5) if own else (n, 5))
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"u": u.astype(np.float32), "y_past": yp.astype(np.float32)})[0]
    # D from the model layer's function (T_out at the fixed reference), floored
    d = np.maximum(ventilation_driver(gh, u[..., 1], T_OUT_REF, u[..., 0]), drv.floor)  # (n, 6)
    assert np.all(d[:3] == pytest.approx(drv.floor))
    plain = Narx(*args, members[0], members=members)  # the same layers on openings, no transform
    z = plain.reduce(u).reshape(n, -1)
    if own:
        opening = np.column_stack([
            Narx(*args, m).forward(np.concatenate([z, (yp[:, j] / d[:, 1:] - 0.05) / 0.04], axis=1))
            for j, m in enumerate(members)]) * 0.04 + 0.05
        want = opening * d[:, :1]
    else:
        opening = plain.forward(np.concatenate([z, (yp / d[:, 1:] - 0.05) / 0.04], axis=1)) * 0.04 + 0.05
        want = (opening * d[:, 0])[:, None]
    assert got.shape == want.shape
    assert np.allclose(got, want, rtol=1e-4, atol=1e-4)
    assert np.allclose(net.predict(u, yp).reshape(want.shape), want, rtol=1e-9, atol=1e-9)
    assert net.y0 == 1.5  # a flow, not an opening


def test_opening_model_is_reproducible_and_named_in_its_metadata(gh, opening_model):
    again = vd.tiny_model("opening-b", ensemble=2, target="opening")
    assert opening_model.read_bytes() == again.read_bytes()
    meta = {p.key: p.value for p in onnx.load(str(opening_model)).metadata_props}
    assert meta["target_kind"] == "opening"
    drv = json.loads(meta["opening_driver"])
    assert drv["b"] == pytest.approx(float(ventilation_driver(gh, 1.0, T_OUT_REF, 0.0)) ** 2)
    assert json.loads(meta["training_settings"])["target_transform"] == "opening"
    linear = {p.key: p.value for p in onnx.load(str(opening_model.with_name(
        "tiny.linear_arx.onnx"))).metadata_props}
    assert "target_kind" not in linear  # the linear ARX stays on the flow
    flow_model = {p.key: p.value for p in onnx.load(str(vd.tiny_model())).metadata_props}
    assert "target_kind" not in flow_model and "opening_driver" not in flow_model
    sensor = VentSensor(opening_model, gh, "almeria")
    est = sensor.step({"t_in": 24.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 55.0, "wind": 3.0},
                      dict.fromkeys(feature_names("almeria")[3:], 0.0))
    assert np.isfinite(est.flow) and est.flow >= 0


def test_a_mismatched_target_is_refused(gh, opening_model, tmp_path):
    meta = {p.key: p.value for p in onnx.load(str(opening_model)).metadata_props}
    drv = json.loads(meta["opening_driver"])
    bad = vd.rewrite_metadata(opening_model, tmp_path / "kind.onnx", target_kind="velocity")
    with pytest.raises(ModelMismatch, match="target kind 'velocity'"):
        VentSensor(bad, gh, "almeria")
    bad = vd.rewrite_metadata(opening_model, tmp_path / "nodriver.onnx", opening_driver=None)
    with pytest.raises(ModelMismatch, match="without its driver"):
        VentSensor(bad, gh, "almeria")
    bad = vd.rewrite_metadata(opening_model, tmp_path / "driver.onnx",
                              opening_driver={**drv, "b": drv["b"] * 1.01})
    with pytest.raises(ModelMismatch, match="opening driver b"):
        VentSensor(bad, gh, "almeria")
    bad = vd.rewrite_metadata(vd.tiny_model(), tmp_path / "flow-as-opening.onnx", target_kind="opening")
    with pytest.raises(ModelMismatch, match="without its driver"):
        VentSensor(bad, gh, "almeria")

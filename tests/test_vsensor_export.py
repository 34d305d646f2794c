"""Virtual ventilation sensor, the exported ONNX graph: PCA and metadata, the code probe, the
numpy network's equivalence, ensembles and transformed targets."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.vsensor.features import feature_names
from tests import vsensor_data as vd


def test_exported_graph_has_pca_and_metadata():
    path = vd.tiny_model()
    model = onnx.load(str(path))
    meta = {p.key: p.value for p in model.metadata_props}
    for key in ("features", "input_delays", "output_delays", "model_kind", "training_ranges",
                "metrics", "data_fingerprint", "version", "pca", "greenhouse", "online_overrides",
                "code_probe"):
        assert key in meta, key
    ops = [n.op_type for n in model.graph.node]
    assert "MatMul" in ops and ops.count("Gemm") == 3  # PCA, then 8-8-1
    import json

    pca = json.loads(meta["pca"])
    assert pca["variance_total"] >= 0.90 and pca["components"] < len(feature_names("almeria"))
    card = path.with_suffix(".md").read_text()
    assert "correlation_circle.png" in card and "| Q_vent [W m-2] | calm |" in card
    assert "Trained with: `python -m training.vsensor train --data train-grower.csv train-controller." in card
    assert "--set t_in.iterations=2" in card and "--pca-variance 0.9 --out tiny.onnx`" in card
    report = path.with_name("tiny.report")
    assert (report / "correlation_circle.png").stat().st_size > 10_000


def test_code_probe_names_a_change_of_the_model_layer(monkeypatch):
    """The probe stored in a model catches what made the shipped model stale before: another
    integration step or another sky temperature, with names still matching."""
    from dataclasses import replace

    from gateway.model import sky, step
    from gateway.vsensor import probe

    gh = load_greenhouse(vd.GREENHOUSE)
    stored = probe.code_probe("almeria", gh)
    assert probe.probe_differences(stored, "almeria", gh) == []
    built = probe.build_model
    monkeypatch.setattr(probe, "build_model",
                        lambda kind, g: replace(built(kind, g), integration=step.FROZEN))
    diffs = probe.probe_differences(stored, "almeria", gh)
    assert len(diffs) == 1 and diffs[0].startswith("one_step_t_in: trained with")
    monkeypatch.setattr(probe, "build_model", built)
    monkeypatch.setattr(sky, "sky_temperature", lambda t_out, rh_out, cloud: t_out - 20.0)
    assert any(d.startswith("t_sky:") for d in probe.probe_differences(stored, "almeria", gh))


def test_onnx_matches_the_numpy_network():
    from training.vsensor import fit
    from training.vsensor.narx import Layer, Narx

    rng = np.random.default_rng(0)
    f = 8
    net = Narx("pca_narx", rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, 3)), 2.0, 1.5,
               [Layer(rng.normal(size=(23, 8)), rng.normal(size=8), "tanh"),
                Layer(rng.normal(size=(8, 1)), rng.normal(size=1), "identity")])
    from training.vsensor.export import write_model

    path = vd.workdir() / "random.onnx"
    write_model(net, f, {"model_kind": "almeria"}, path)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    u = rng.normal(size=(50, 6, f))
    yp = rng.uniform(0, 5, size=(50, 5))
    got = sess.run(None, {"u": u.astype(np.float32), "y_past": yp.astype(np.float32)})[0][:, 0]
    assert np.allclose(got, net.predict(u, yp), rtol=1e-4, atol=1e-4)
    del fit


def test_ensemble_graph_averages_its_members():
    """An ensemble in one graph: shared pre-processing, the members' outputs averaged (ONNX
    Mean), the same flows as the numpy mean of the single networks."""
    from training.vsensor.export import write_model
    from training.vsensor.narx import Layer, Narx

    rng = np.random.default_rng(1)
    f = 8

    def stack():
        return [Layer(rng.normal(size=(23, 8)), rng.normal(size=8), "tanh"),
                Layer(rng.normal(size=(8, 1)), rng.normal(size=1), "identity")]

    members = [stack() for _ in range(3)]
    args = ("pca_narx", rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, 3)), 2.0, 1.5)
    net = Narx(*args, members[0], members=members)
    path = vd.workdir() / "ensemble.onnx"
    write_model(net, f, {"model_kind": "almeria"}, path)
    ops = [n.op_type for n in onnx.load(str(path)).graph.node]
    assert ops.count("Gemm") == 6 and ops.count("Mean") == 1 and ops.count("MatMul") == 1
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    u = rng.normal(size=(40, 6, f))
    yp = rng.uniform(0, 5, size=(40, 5))
    got = sess.run(None, {"u": u.astype(np.float32), "y_past": yp.astype(np.float32)})[0][:, 0]
    singles = [Narx(*args, m).predict(u, yp) for m in members]
    assert np.allclose(net.predict(u, yp), np.mean(singles, axis=0))
    assert np.allclose(got, np.mean(singles, axis=0), rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("target", ["sqrt", "log1p"])
def test_transformed_target_graph_takes_and_gives_flows(target):
    """A network on √G or log(1 + G): the graph transforms the past flows and inverts its
    output, so it matches the numpy network in flows; y0 is the median flow, not its transform."""
    from training.vsensor.export import write_model
    from training.vsensor.narx import Layer, Narx, from_target, to_target

    rng = np.random.default_rng(2)
    f = 8
    members = [[Layer(rng.normal(size=(23, 8)), rng.normal(size=8), "tanh"),
                Layer(rng.normal(size=(8, 1)), rng.normal(size=1), "identity")] for _ in range(2)]
    net = Narx("pca_narx", rng.normal(size=f), rng.uniform(0.5, 2, f), rng.normal(size=(f, 3)),
               1.2, 0.8, members[0], members=members, target=target)
    path = vd.workdir() / f"target-{target}.onnx"
    write_model(net, f, {"model_kind": "almeria"}, path)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    u = rng.normal(size=(40, 6, f))
    yp = rng.uniform(0, 9, size=(40, 5))
    got = sess.run(None, {"u": u.astype(np.float32), "y_past": yp.astype(np.float32)})[0][:, 0]
    want = net.predict(u, yp)
    assert np.allclose(got, want, rtol=1e-4, atol=1e-4)
    ident = Narx("pca_narx", net.mean, net.std, net.projection, 1.2, 0.8, members[0],
                 members=members)
    scaled = ident.forward(np.concatenate(
        [ident.reduce(u).reshape(40, -1), (to_target(yp, target) - 1.2) / 0.8], axis=1))
    assert np.allclose(want, from_target(scaled * 0.8 + 1.2, target))
    assert net.y0 == pytest.approx(float(from_target(np.array(1.2), target)))
    y = np.array([0.0, 0.3, 4.0, 50.0])
    assert np.allclose(from_target(to_target(y, target), target), y)

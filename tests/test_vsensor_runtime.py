"""Run-time side of the virtual ventilation sensor: VentSensor, the batch run, the CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

from gateway.cli import main as gateway_main
from gateway.estimate.online import OnlineEstimator, online_settings
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.series import load_series
from gateway.vsensor import ModelMismatch, VentSensor, fluxes_now
from gateway.vsensor.batch import run_sensor
from gateway.vsensor.features import feature_names, filter_gains, flow_limits, low_pass, raw_features
from gateway.vsensor.loop import closed_loop, fill_missing
from tests import vsensor_data as vd

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def gh():
    return load_greenhouse(vd.GREENHOUSE)


@pytest.fixture(scope="module")
def model_path():
    return vd.tiny_model()


@pytest.fixture(scope="module")
def novent(gh):
    return vd.novent_run(gh)


def test_prototype_leakage_flow_carries_the_leakage_heat_loss(gh):
    """c_loss is a flow per floor area [m s-1] (III.14, III.19): the flow the sensor's range
    counts for it, G = c_loss S_f, loses through III.32 (ρ c_p G ΔT / S_f) the heat the
    model's leakage term loses (its lumped flux × C_a)."""
    from gateway.model.prototype import AirLeakage
    from gateway.model.psychrometrics import CP_AIR

    proto = build_model("prototype", gh)
    c_loss = float(proto.bounds(gh)[1][proto.index("c_loss")])
    g = flow_limits(gh, "prototype").leak  # [m3 s-1]
    x, t_in = {"t_out": np.array([5.0])}, np.array([[15.0]])
    q_model = -AirLeakage(gh.air_density).flux({"c_loss": np.array([[c_loss]])}, x, t_in,
                                                slice(0, 1))[0, 0] * CP_AIR
    q_vent = gh.air_density * CP_AIR * g * 10.0 / gh.floor_area  # III.32
    assert gh.volume / gh.floor_area > 1.5  # a house where × V and × S_f differ
    np.testing.assert_allclose(q_vent, q_model, rtol=1e-12)


def _with_meta(src: Path, dst: Path, **changes) -> Path:
    model = onnx.load(str(src))
    for p in model.metadata_props:
        if p.key in changes:
            p.value = changes[p.key] if isinstance(changes[p.key], str) else json.dumps(changes[p.key])
    onnx.save(model, str(dst))
    return dst


def test_step_equals_the_batch_closed_loop(gh, model_path, novent):
    """VentSensor.step, minute by minute, is the closed loop (loop.closed_loop) of the same graph."""
    sensor = VentSensor(model_path, gh, "almeria")
    run = run_sensor(sensor, novent)
    inputs = low_pass(raw_features("almeria", novent.x, novent.fluxes), filter_gains("almeria"))
    filled, _ = fill_missing(inputs, sensor.info.mean)
    x = novent.x
    upper = flow_limits(gh, "almeria").upper(x["t_in"] - x["t_out"], x["t_out"], x["wind"])
    sess = ort.InferenceSession(str(model_path), providers=["CPUExecutionProvider"])

    def predict(u, y_past):
        feeds = {"u": u.astype(np.float32), "y_past": y_past.astype(np.float32)}
        return sess.run(None, feeds)[0]  # (N, K): one flow per output history

    batch = closed_loop(predict, filled[None], upper[None], sensor.info.y0, sensor.histories)[0]
    assert np.allclose(run.flow, batch, rtol=1e-5, atol=1e-5)
    assert np.all(np.isfinite(run.flow)) and run.flow.min() >= 0.0
    assert np.all(np.isfinite(run.q_vent))


@pytest.mark.parametrize("clamp", [False, True])
def test_nan_and_out_of_range_inputs_are_flagged_never_nan_or_negative(gh, model_path, clamp):
    """Absurd inputs give a finite, non-negative flow and stay flagged, clamped or not."""
    sensor = VentSensor(model_path, gh, "almeria", clamp_inputs=clamp)
    names = feature_names("almeria")[3:]
    good_m = {"t_in": 22.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 60.0, "wind": 3.0}
    good_f = {n: 0.0 for n in names}
    est = sensor.step(good_m, good_f)
    assert est.flow >= 0 and math.isfinite(est.q_vent)
    cases = [
        ({**good_m, "wind": float("nan")}, good_f),
        ({"t_in": None, "t_out": "bad"}, {}),
        ({**good_m, "t_in": 65.0, "wind": 70.0}, {n: 1e6 for n in names}),
        (good_m, {n: -1e6 for n in names}),
        ({k: float("inf") for k in good_m}, {n: float("nan") for n in names}),
    ]
    for m, f in cases:
        est = sensor.step(m, f)
        assert math.isfinite(est.flow) and est.flow >= 0.0, (m, f, est)
        assert math.isfinite(est.q_vent)
        assert not est.valid and (est.missing or est.out_of_range)
    c = sensor.counts
    assert c.steps == 6 and c.flagged == 5
    assert c.missing["wind"] >= 2 and c.out_of_range_steps >= 2
    assert sum(c.missing.values()) >= 1 + 8 + 3
    assert c.inputs_clamped == (c.out_of_range_steps if clamp else 0)


def _narrow(model: Path, dst: Path) -> Path:
    """The model with its training ranges shrunk to their middle fifth: the test file then
    drives every input outside them often, so the clamp acts."""
    info = VentSensor(model, load_greenhouse(vd.GREENHOUSE), "almeria").info
    mid, span = info.ranges.mean(axis=1), info.ranges[:, 1] - info.ranges[:, 0]
    ranges = {n: [float(m - s / 10), float(m + s / 10)]
              for n, m, s in zip(info.names, mid, span, strict=True)}
    return vd.rewrite_metadata(model, dst, training_ranges=ranges)


def _fed_rows(sensor: VentSensor, novent) -> np.ndarray:
    """The rows the graph was fed at every step (u at delay 0), as run_sensor steps."""
    cols = {k: novent.x[k] for k in ("t_in", "t_out", "rh_in", "rh_out", "wind")}
    rows = []
    for t in range(len(novent.time)):
        sensor.step({k: v[t] for k, v in cols.items()}, {k: v[t] for k, v in novent.fluxes.items()})
        rows.append(sensor._u[0, 0].copy())
    return np.array(rows)


def test_the_input_clamp_keeps_inputs_in_bounds_and_in_range_inputs_bit_identical(
        gh, model_path, novent, tmp_path):
    """clamp_inputs: an input outside its padded training range is fed at the bound it crossed
    (still flagged, counted alike), an input inside it is fed bit for bit as without the clamp;
    the batch closed loop (loop.closed_loop bounds) feeds the network the same."""
    from gateway.vsensor.loop import padded_ranges

    narrow = _narrow(model_path, tmp_path / "narrow.onnx")
    off, on = VentSensor(narrow, gh, "almeria"), VentSensor(narrow, gh, "almeria", clamp_inputs=True)
    rows_off, rows_on = _fed_rows(off, novent), _fed_rows(on, novent)
    lo, hi = padded_ranges(on.info.ranges)
    inside = (rows_off >= lo.astype(np.float32)) & (rows_off <= hi.astype(np.float32))
    assert (~inside).any(axis=0).sum() >= 3  # several inputs cross their bounds
    assert np.array_equal(rows_on[inside], rows_off[inside])
    assert np.all(rows_on >= lo.astype(np.float32)) and np.all(rows_on <= hi.astype(np.float32))
    below = np.broadcast_to(lo.astype(np.float32), rows_on.shape)
    above = np.broadcast_to(hi.astype(np.float32), rows_on.shape)
    low_cells = rows_off < below
    assert np.array_equal(rows_on[low_cells], below[low_cells])
    assert np.array_equal(rows_on[rows_off > above], above[rows_off > above])
    assert on.counts.out_of_range == off.counts.out_of_range  # the flag is not hidden
    assert on.counts.inputs_clamped == on.counts.out_of_range_steps > 0
    assert off.counts.inputs_clamped == 0
    seen = []

    def predict(u, y_past):
        seen.append(u[:, 0].copy())
        return np.ones((u.shape[0], 1))

    raw = np.where(inside, rows_off, rows_off * 10.0)[None].astype(float)
    closed_loop(predict, raw, np.full(raw.shape[:2], 1e9), 0.0, bounds=(lo, hi))
    fed = np.concatenate(seen)
    assert np.all(fed >= lo) and np.all(fed <= hi)
    assert np.array_equal(fed[inside], raw[0][inside])


def test_clamped_sensor_runs_live_as_the_batch_closed_loop(gh, model_path, tmp_path):
    """With the clamp on, the gateway's VentSensor and training's batch closed loop
    (simulate_model, the path of tune's clamped scoring) give the same flows."""
    narrow = _narrow(model_path, tmp_path / "narrow.onnx")
    sensor, live, batch = vd.live_and_batch(narrow, gh, clamp_inputs=True)
    assert sensor.counts.inputs_clamped > 100
    assert np.allclose(live, batch, rtol=1e-5, atol=1e-5)
    assert np.all(np.isfinite(live)) and live.min() >= 0.0
    _, unclamped, _ = vd.live_and_batch(narrow, gh)
    assert not np.allclose(live, unclamped, rtol=1e-3, atol=1e-3)


def test_other_greenhouse_is_flagged(tmp_path, model_path):
    text = (ROOT / "gateway/presets/almeria-palmerillas.toml").read_text()
    other = tmp_path / "other.toml"
    other.write_text(text.replace("side_count = 2", "side_count = 1")
                     .replace("roof_count = 5", "roof_count = 2"))
    sensor = VentSensor(model_path, load_greenhouse(other), "almeria")
    assert sensor.mismatch and "side_vent_area_m2" in " ".join(sensor.mismatch)
    est = sensor.step({"t_in": 22.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 60.0, "wind": 3.0},
                      {n: 0.0 for n in feature_names("almeria")[3:]})
    assert est.other_greenhouse and not est.valid


def test_refuses_a_model_that_does_not_fit_the_code(gh, model_path, tmp_path):
    meta = {p.key: p.value for p in onnx.load(str(model_path)).metadata_props}
    feats = json.loads(meta["features"])
    swapped = [feats[1], feats[0], *feats[2:]]
    bad = _with_meta(model_path, tmp_path / "swapped.onnx", features=swapped)
    with pytest.raises(ModelMismatch, match="feature order differs"):
        VentSensor(bad, gh, "almeria")
    with pytest.raises(ModelMismatch, match="trained on fluxes of the 'almeria' model.*'prototype'"):
        VentSensor(model_path, load_greenhouse("biskra-prototype"), "prototype")
    renamed = [*feats[:-1], {**feats[-1], "name": "q_leak"}]
    bad = _with_meta(model_path, tmp_path / "renamed.onnx", features=renamed)
    with pytest.raises(ModelMismatch, match="lacks q_vent and has q_leak"):
        VentSensor(bad, gh, "almeria")
    bad = _with_meta(model_path, tmp_path / "delays.onnx", input_delays=[0, 1, 2])
    with pytest.raises(ModelMismatch, match="input_delays"):
        VentSensor(bad, gh, "almeria")
    tau = [{**f, "tau_s": 60.0} if f["name"] == "wind" else f for f in feats]
    bad = _with_meta(model_path, tmp_path / "tau.onnx", features=tau)
    with pytest.raises(ModelMismatch, match="wind filtered with tau 60"):
        VentSensor(bad, gh, "almeria")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(ModelMismatch, match="cannot load"):
        VentSensor(junk, gh, "almeria")


def test_fluxes_now_feeds_the_sensor_live(gh, model_path):
    """The live path: OnlineEstimator.update, then fluxes_now, then VentSensor.step."""
    model = build_model("almeria", gh)
    est = OnlineEstimator(model, gh, model.defaults(gh), online_settings(model, gh, vd.TINY))
    series = load_series(str(vd.test_file()))
    sensor = VentSensor(model_path, gh, "almeria")
    for t in range(30):
        row = {k: float(v[t]) for k, v in series.columns.items() if k not in ("vent_roof", "vent_side")}
        est.update(row)
        fluxes = fluxes_now(est)
        assert set(feature_names("almeria")[3:]) <= set(fluxes)
        out = sensor.step(row, fluxes)
        assert out.flow >= 0.0 and math.isfinite(out.flow)
    assert sensor.counts.steps == 30 and sensor.counts.missing_steps == 0


def test_a_snapshot_resumes_the_closed_loop_exactly(gh, model_path, novent, tmp_path):
    """snapshot → JSON → restore into a new VentSensor of the same file: the next steps are the
    ones the first sensor takes; another model file's snapshot is refused, history untouched."""
    names = feature_names("almeria")[3:]

    def rows(lo: int, hi: int):
        for t in range(lo, hi):
            yield ({k: float(v[t]) for k, v in novent.x.items()},
                   {k: float(novent.fluxes[k][t]) for k in names})

    first = VentSensor(model_path, gh, "almeria")
    for m, q in rows(0, 120):
        first.step(m, q)
    saved = json.loads(json.dumps(first.snapshot()))
    again = VentSensor(model_path, gh, "almeria")
    again.restore(saved)
    a = [first.step(m, q).flow for m, q in rows(120, 180)]
    b = [again.step(m, q).flow for m, q in rows(120, 180)]
    fresh = VentSensor(model_path, gh, "almeria")
    c = [fresh.step(m, q).flow for m, q in rows(120, 180)]
    assert a == b and a != c  # the history matters, and it is carried whole
    other = VentSensor(vd.rewrite_metadata(model_path, tmp_path / "o.onnx", version="other"), gh,
                       "almeria")
    before = other.snapshot()
    with pytest.raises(ValueError, match="another model"):
        other.restore(saved)
    assert json.dumps(other.snapshot()) == json.dumps(before)


def test_cli_json_scores_against_the_explicit_flow_beside_the_baselines(model_path):
    code, rep, out = vd.cli_run(model_path)  # the CLI's own run, shared with test_vsensor_train
    assert code == 0
    for block in (rep, *rep["baselines"].values()):
        for key in ("flow", "q_vent"):
            assert set(block[key]) >= {"mae", "rmse", "maxae", "r2", "mae_pct_range"}
        assert block["flow_error_pct"] == pytest.approx(block["flow"]["mae_pct_range"])
        assert block["steps"] == 1440 and "out_of_range" in block
    assert set(rep["baselines"]) == {"narx_no_pca", "linear_arx"}
    lines = out.read_text().splitlines()
    assert lines[0] == "time,flow_m3_s,q_vent_w_m2,out_of_range,valid,explicit_flow_m3_s"
    assert len(lines) == 1441 and all(float(r.split(",")[1]) >= 0 for r in lines[1:])


def test_cli_errors_are_one_line(tmp_path, model_path, capsys):
    code = gateway_main(["vsensor", "--model", str(model_path), "--data", str(vd.test_file()),
                         "--greenhouse", "biskra-prototype", "--model-kind", "prototype"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "'almeria' model" in err and "\n" not in err


def test_gateway_never_imports_sklearn_or_training():
    code = ("import sys, gateway.vsensor, gateway.vsensor.batch, gateway.cli.vsensor, "
            "gateway.vsensor.models; bad = [m for m in sys.modules if m.split('.')[0] in "
            "('sklearn', 'training', 'onnx', 'scipy')]; print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    for path in (ROOT / "gateway").rglob("*.py"):
        text = path.read_text()
        assert "import sklearn" not in text and "from sklearn" not in text, path
    for path in [*(ROOT / "gateway/vsensor").rglob("*.py"), ROOT / "gateway/cli/vsensor.py"]:
        text = path.read_text()
        assert "from training" not in text and "import training" not in text, path


# the shipped sensors: kind → the extra inputs it was trained with (docs/vsensor.md)
SHIPPED = {"almeria": (), "prototype": ("vpd_in",)}


@pytest.mark.parametrize("kind", list(SHIPPED))
def test_shipped_model_matches_the_code_that_feeds_it(kind):
    """The models in the wheel: the metadata names exactly what gateway/vsensor/features.py
    computes, each is small, loads and runs, and the baselines sit beside it. ``prototype`` reads
    the kit's columns only and learnt the almeria model's flow (``target_kind``)."""
    from gateway.vsensor.batch import BASELINES
    from gateway.vsensor.features import INPUT_DELAYS, OUTPUT_DELAYS, features
    from gateway.vsensor.models import shipped_model
    from gateway.vsensor.probe import probe_differences

    path = shipped_model(kind)
    assert path.stat().st_size <= 1_000_000
    gh = load_greenhouse("almeria-palmerillas")
    sensor = VentSensor(path, gh, kind)  # raises ModelMismatch if anything differs
    meta = sensor.info.meta
    want = features(kind, SHIPPED[kind])
    assert [f["name"] for f in meta["features"]] == [f.name for f in want]
    assert [f["unit"] for f in meta["features"]] == [f.unit for f in want]
    assert meta.get("target_model_kind", kind) == "almeria"  # both learnt the almeria model's flow
    assert meta["input_delays"] == list(INPUT_DELAYS) and meta["output_delays"] == list(OUTPUT_DELAYS)
    assert meta["model_kind"] == kind and meta["network"] == "pca_narx"
    assert meta["pca"]["variance_total"] >= 0.90
    assert 2 <= len(meta["hidden_layers"]) <= 3 and all(20 <= h <= 50 for h in meta["hidden_layers"])
    assert not sensor.mismatch  # trained on the preset's house
    # trained on the fluxes this code computes (flux terms, sky temperature, step): else retrain
    diffs = probe_differences(meta.get("code_probe", {}), kind, gh)
    assert not diffs, f"{path.name} was trained on other fluxes; retrain (docs/vsensor.md): {diffs}"
    if "target_code_probe" in meta:  # and its target on the almeria model's fluxes of this code
        diffs = probe_differences(meta["target_code_probe"], "almeria", gh)
        assert not diffs, f"{path.name}'s target came from other fluxes; retrain: {diffs}"
    for name in BASELINES:
        VentSensor(path.with_name(f"{kind}.{name}.onnx"), gh, kind)
    assert path.with_suffix(".md").exists()
    est = sensor.step({"t_in": 24.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 55.0, "wind": 3.0},
                      dict.fromkeys(feature_names(kind)[3:], 0.0))
    assert math.isfinite(est.flow) and est.flow >= 0
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"**/*.onnx"' in pyproject  # package data: the appliance wheel carries it (test_images)

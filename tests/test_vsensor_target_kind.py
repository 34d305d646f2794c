"""A sensor fed by one model kind and trained on another kind's explicit flow (``--target-kind``):
kit-only inputs (the prototype model's no-vent fluxes) and the almeria model's vent-based flow as
the target, which needs t_soil to train and to score, never to run (docs/vsensor.md)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import onnx
import pytest

from gateway.cli import main as gateway_main
from gateway.greenhouse import load_greenhouse
from gateway.series import load_series
from gateway.vsensor.batch import run_series
from gateway.vsensor.features import feature_names
from gateway.vsensor.probe import probe_differences
from tests import vsensor_data as vd
from training.vsensor.dataset import build_segment, cache_key, file_sha256


@pytest.fixture(scope="module")
def gh():
    return load_greenhouse(vd.GREENHOUSE)


@pytest.fixture(scope="module")
def model() -> Path:
    return vd.tiny_model("target-kind", kind="prototype", target_kind="almeria")


def meta_of(path: Path) -> dict:
    return {p.key: p.value for p in onnx.load(str(path)).metadata_props}


def without_column(src: Path, dst: Path, column: str) -> Path:
    """A copy of the kit CSV ``src`` without ``column`` (what a kit writes: no t_soil)."""
    with open(src, newline="") as f:
        rows = list(csv.DictReader(f))
    keep = [c for c in rows[0] if c != column]
    with open(dst, "w", newline="") as f:
        w = csv.DictWriter(f, keep, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    return dst


def test_inputs_from_the_input_kind_target_from_the_target_kind(gh):
    """The inputs are the prototype segment's, the flow the almeria segment's; the prototype
    replay with the vents is not run: its no-vent replay is cached alone, without a flow."""
    cache, path = vd.workdir() / "cache", vd.train_files()[1]
    mixed = build_segment(path, gh, "prototype", cache, vd.TINY, target_kind="almeria")
    novent = cache / f"{path.stem}-{cache_key(file_sha256(path), gh, 'prototype', vd.TINY, 0, 'novent')}.npz"
    with np.load(novent) as data:
        assert "flow" not in data.files and "flux_q_solar" in data.files
    alm = build_segment(path, gh, "almeria", cache, vd.TINY)
    proto = build_segment(path, gh, "prototype", cache, vd.TINY)
    assert mixed.inputs.shape[1] == len(feature_names("prototype"))
    np.testing.assert_array_equal(mixed.inputs, proto.inputs)
    np.testing.assert_array_equal(mixed.flow, alm.flow)
    assert not np.array_equal(proto.flow[60:], alm.flow[60:])  # the two kinds' flows differ
    again = build_segment(path, gh, "prototype", cache, vd.TINY, target_kind="prototype")
    np.testing.assert_array_equal(again.flow, proto.flow)  # the default: the input kind's flow


def test_metadata_keeps_the_feeding_kind_and_names_the_target_kind(gh, model):
    meta = meta_of(model)
    assert meta["model_kind"] == "prototype" and meta["target_model_kind"] == "almeria"
    assert "adaptive almeria model" in meta["target"]
    assert not probe_differences(json.loads(meta["target_code_probe"]), "almeria", gh)
    card = model.with_suffix(".md").read_text()
    assert "--model prototype --target-kind almeria" in card
    assert "**Target model kind: almeria** (inputs: prototype)" in card
    plain = meta_of(vd.tiny_model())  # a default model: neither key, so its bytes are unchanged
    assert "target_model_kind" not in plain and "target_code_probe" not in plain


def test_the_score_is_against_the_target_kinds_explicit_flow(gh, model):
    """``python -m gateway vsensor``'s reference is the flow the sensor learned (almeria's)."""
    series = load_series(str(vd.test_file()), step=60.0)
    result = run_series(model, series, gh, "prototype")
    assert result.reference_kind == "almeria" and result.reference_flow is not None
    alm = build_segment(vd.test_file(), gh, "almeria", vd.workdir() / "cache", vd.TINY)
    np.testing.assert_allclose(result.reference_flow[60:], alm.flow[60:], rtol=1e-12)


def test_a_csv_without_t_soil_gets_flows_and_a_note_instead_of_a_score(tmp_path, model, capsys):
    data = without_column(vd.test_file(), tmp_path / "kit.csv", "t_soil")
    out = tmp_path / "flows.csv"
    code = gateway_main(["vsensor", "--sensor", str(model), "--data", str(data), "--greenhouse",
                         vd.GREENHOUSE, "--model-kind", "prototype", "--json", "--out", str(out)])
    assert code == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["reference"] is None and rep["flow"] is None and rep["steps"] == 1440
    assert any(n["code"] == "not_scored" and "'almeria' model" in n["message"]
               and "t_soil" in n["message"] for n in rep["notes"])
    lines = out.read_text().splitlines()
    assert lines[0] == "time,flow_m3_s,q_vent_w_m2,out_of_range,valid"
    flows = [float(r.split(",")[1]) for r in lines[1:]]
    assert len(flows) == 1440 and all(math.isfinite(v) and v >= 0 for v in flows)


def test_the_progress_bar_counts_only_the_replays_that_run(tmp_path, gh, model):
    """Two replays (no vents, then the target kind's with them) when the CSV can be scored, one
    when it cannot (no t_soil for the almeria flow) or carries no vents: the bar's size."""
    from gateway.vsensor.adaptive import without_vents
    from gateway.vsensor.batch import replays_needed
    from gateway.vsensor.runtime import VentSensor

    sensor = VentSensor(model, gh, "prototype")
    full = load_series(str(vd.test_file()), step=60.0)
    kit = load_series(str(without_column(vd.test_file(), tmp_path / "kit.csv", "t_soil")), step=60.0)
    assert replays_needed(sensor, full, gh, "prototype") == 2
    assert replays_needed(sensor, kit, gh, "prototype") == 1
    assert replays_needed(sensor, without_vents(full), gh, "prototype") == 1

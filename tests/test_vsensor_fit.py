"""gateway/vsensor/fit.py: which house the shipped sensors learnt, read off their ONNX files
without onnxruntime, and the status screen's reason when none fits the greenhouse."""

from __future__ import annotations

from pathlib import Path

import onnxruntime as ort
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.vsensor.fit import metadata, no_sensor_reason, trained_houses
from gateway.vsensor.models import MODEL_DIR

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("path", sorted(MODEL_DIR.glob("*.onnx")), ids=lambda p: p.name)
def test_the_metadata_read_off_the_file_is_onnxruntimes(path: Path) -> None:
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    want = dict(session.get_modelmeta().custom_metadata_map)
    assert "greenhouse" in want and metadata(path) == want


def test_the_reason_names_the_house_the_shipped_sensors_learnt(tmp_path: Path) -> None:
    assert set(trained_houses()) == {"almeria-palmerillas"}
    # make run's house (0.68 m2, no vents) and a vented house of other vent areas: another house
    for house in ("biskra-prototype", str(ROOT / "docs/examples/other-house.toml")):
        assert no_sensor_reason(load_greenhouse(house)) == "shipped ones fit almeria-palmerillas only"
    # the house they learnt: nothing to explain (gateway.toml's vsensor = may name one)
    assert no_sensor_reason(load_greenhouse("almeria-palmerillas")) == ""
    # no model in the folder: no reason claimed; a file that is not ONNX: refused by name
    assert no_sensor_reason(load_greenhouse("biskra-prototype"), tmp_path) == ""
    (tmp_path / "x.onnx").write_bytes(b"\xff" * 12)
    with pytest.raises(ValueError, match="not an ONNX file"):
        trained_houses(tmp_path)

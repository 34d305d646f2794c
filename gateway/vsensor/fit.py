"""Whether a shipped sensor fits a greenhouse: the reason the status screen gives when none is set.

A sensor learnt the flow of the house it was trained on (its metadata's ``greenhouse``
signature: floor, volume, vent areas, vent height; docs/vsensor.md, "Another greenhouse"); on
another house it flags every step. ``make run``'s house (biskra-prototype, 0.68 m2, no vents) is
such a house for both shipped sensors (trained on almeria-palmerillas, 877 m2): the screen says
why there is no sensor instead of only that there is none (README, "make run").
"""

from __future__ import annotations

import json
from pathlib import Path

from gateway.greenhouse import Greenhouse
from gateway.vsensor.features import greenhouse_signature, signature_mismatch
from gateway.vsensor.models import MODEL_DIR


def trained_houses(folder: Path = MODEL_DIR) -> dict[str, dict[str, float]]:
    """The house name → signature of every shipped sensor (``<kind>.onnx``, not its baselines)."""
    import onnxruntime as ort

    out: dict[str, dict[str, float]] = {}
    for path in sorted(folder.glob("*.onnx")):
        if "." in path.stem:  # <kind>.<baseline>.onnx: the same house as <kind>.onnx
            continue
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        meta = session.get_modelmeta().custom_metadata_map
        house = json.loads(meta.get("greenhouse", "{}"))
        if house.get("signature"):
            out[str(house.get("name", path.stem))] = house["signature"]
    return out


def no_sensor_reason(gh: Greenhouse, folder: Path = MODEL_DIR) -> str:
    """Why no shipped sensor can serve ``gh`` (a few words for the screen's ventilation line),
    or "" when one was trained on this house (``vsensor =`` in gateway.toml may name it)."""
    houses = trained_houses(folder)
    here = greenhouse_signature(gh)
    if not houses or any(not signature_mismatch(sig, here) for sig in houses.values()):
        return ""
    if len(houses) == 1:
        return f"shipped ones fit {next(iter(houses))} only"
    return "shipped ones fit other houses"

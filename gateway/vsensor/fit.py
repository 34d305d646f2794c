"""Whether a shipped sensor fits a greenhouse: the reason the status screen gives when none is set.

A sensor learnt the flow of the house it was trained on (its metadata's ``greenhouse``
signature: floor, volume, vent areas, vent height; docs/vsensor.md, "Another greenhouse"); on
another house it flags every step. ``make run``'s house (biskra-prototype, 0.68 m2, no vents) is
such a house for both shipped sensors (trained on almeria-palmerillas, 877 m2): the screen says
why there is no sensor instead of only that there is none (README, "make run"). The signatures
are read off the ONNX files' metadata without onnxruntime: the screen runs no model.
"""

from __future__ import annotations

import json
from pathlib import Path

from gateway.greenhouse import Greenhouse
from gateway.vsensor.features import greenhouse_signature, signature_mismatch
from gateway.vsensor.models import MODEL_DIR

METADATA_PROPS = 14
"""``ModelProto.metadata_props`` (onnx.proto): repeated ``StringStringEntryProto`` {key = 1,
value = 2}, where the training writes the sensor's metadata (docs/vsensor.md)."""


def metadata(path: Path) -> dict[str, str]:
    """An ONNX file's ``metadata_props``, read off its top-level protobuf fields: what
    onnxruntime's ``custom_metadata_map`` gives (tested), without loading onnxruntime (~30 MB
    of RSS for a status screen that runs no model)."""
    return dict(_strings(body) for f, body in _fields(path.read_bytes()) if f == METADATA_PROPS)


def _strings(entry: bytes) -> tuple[str, str]:
    kv = {f: body.decode("utf-8") for f, body in _fields(entry) if f in (1, 2)}
    return kv.get(1, ""), kv.get(2, "")


def _fields(buf: bytes) -> list[tuple[int, bytes]]:
    """(field number, bytes) of each length-delimited field of a protobuf message; the other
    wire types (varint, 64-bit, 32-bit) are skipped."""
    out, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            _, i = _varint(buf, i)
        elif wire == 1:
            i += 8
        elif wire == 5:
            i += 4
        elif wire == 2:
            n, i = _varint(buf, i)
            out.append((field, buf[i:i + n]))
            i += n
        else:
            raise ValueError(f"not an ONNX file: protobuf wire type {wire}")
    if i != len(buf):
        raise ValueError("not an ONNX file: truncated protobuf")
    return out


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        if i >= len(buf):
            raise ValueError("not an ONNX file: truncated varint")
        b = buf[i]
        value |= (b & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if b < 0x80:
            return value, i


def trained_houses(folder: Path = MODEL_DIR) -> dict[str, dict[str, float]]:
    """The house name → signature of every shipped sensor (``<kind>.onnx``, not its baselines)."""
    out: dict[str, dict[str, float]] = {}
    for path in sorted(folder.glob("*.onnx")):
        if "." in path.stem:  # <kind>.<baseline>.onnx: the same house as <kind>.onnx
            continue
        house = json.loads(metadata(path).get("greenhouse", "{}"))
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

"""Trained sensors shipped with the gateway (package data, so the appliance wheel carries them).

``<kind>.onnx`` is the PCA-NARX for fluxes of the ``<kind>`` model, ``<kind>.md`` its model
card, ``<kind>.<baseline>.onnx`` the baselines trained beside it. Rebuilt by the commands in
docs/vsensor.md.
"""

from __future__ import annotations

from pathlib import Path

MODEL_DIR = Path(__file__).resolve().parent


def shipped_model(kind: str) -> Path:
    """Path of the shipped sensor for fluxes of the ``kind`` model (FileNotFoundError if none)."""
    path = MODEL_DIR / f"{kind}.onnx"
    if not path.exists():
        shipped = sorted(p.stem for p in MODEL_DIR.glob("*.onnx") if "." not in p.stem)
        raise FileNotFoundError(
            f"no shipped ventilation sensor for the '{kind}' model (shipped: "
            f"{', '.join(shipped) or 'none'}); train one with python -m training.vsensor train "
            f"(docs/vsensor.md) and pass its file (--sensor MODEL.onnx)")
    return path

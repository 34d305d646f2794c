"""Climate models built from heat-flux terms (thesis chapter III)."""

from __future__ import annotations

from gateway.greenhouse import Greenhouse
from gateway.model.model import Model

MODEL_NAMES = ("prototype", "almeria")


def build_model(name: str, gh: Greenhouse) -> Model:
    """``prototype`` (III.14–III.22) or ``almeria`` (III.23–III.35) for greenhouse ``gh``."""
    if name == "prototype":
        from gateway.model.prototype import build_prototype

        return build_prototype(gh)
    if name == "almeria":
        from gateway.model.almeria import build_almeria

        return build_almeria(gh)
    raise ValueError(f"unknown model '{name}' (choose from {', '.join(MODEL_NAMES)})")

"""Climate models built from heat-flux terms (thesis chapter III)."""

from __future__ import annotations

from gateway.greenhouse import Greenhouse, GreenhouseError
from gateway.model.model import Model

VENTED_PROTOTYPE = "prototype+vent_control"
"""The prototype with the air exchange of vents moved by a climate computer or by hand, which the
kit does not see (gateway/model/vent_control.py); the shipped gateway.toml's model (issue 10)."""
HEATED_PROTOTYPE = "prototype+vent_control+heating"
"""The vented prototype with the heat of a thermostat-run heater the kit does not see
(gateway/model/heating_control.py): for a heated house, chosen by its user (docs/effects.md,
"A heated house")."""
PROTOTYPES = ("prototype", VENTED_PROTOTYPE, HEATED_PROTOTYPE)
MODEL_NAMES = (*PROTOTYPES, "almeria")


def build_model(name: str, gh: Greenhouse) -> Model:
    """``prototype`` (III.14–III.22), ``prototype+vent_control`` (the same with two more
    parameters for unseen controller-moved vents), ``prototype+vent_control+heating`` (and two
    more for an unseen thermostat-run heater) or ``almeria`` (III.23–III.35) for ``gh``."""
    if name in PROTOTYPES:
        from gateway.model.prototype import build_prototype

        return build_prototype(gh, vent_control=name != "prototype",
                               heating=name == HEATED_PROTOTYPE)
    if name == "almeria":
        from gateway.model.almeria import build_almeria

        return build_almeria(gh)
    raise ValueError(f"unknown model '{name}' (choose from {', '.join(MODEL_NAMES)})")


def check_parameters(model: Model, gh: Greenhouse) -> None:
    """Raise GreenhouseError for a ``[parameters.<name>]`` that no model knows (a typo would be
    silently ignored) or a ``value`` outside its bounds (it would be silently clipped).

    A parameter of the other model is allowed: one greenhouse file may serve both models.
    """
    known = {n for m in MODEL_NAMES for n in build_model(m, gh).names}
    for name in gh.parameters:
        if name not in known:
            raise GreenhouseError(
                f"{gh.source}: unknown parameter 'parameters.{name}' (the {model.name} model has "
                f"{', '.join(model.names)})"
            )
    lo, hi = model.bounds(gh)
    for j, name in enumerate(model.names):
        value = gh.parameters.get(name, {}).get("value")
        if value is not None and not lo[j] <= value <= hi[j]:
            raise GreenhouseError(
                f"{gh.source}: 'parameters.{name}.value' = {value:g} is outside its bounds "
                f"[{lo[j]:g}, {hi[j]:g}]"
            )

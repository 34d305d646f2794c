"""Online estimator settings: the model's estimation groups with the greenhouse's
``[online.<output>]`` overrides (thesis §IV.2.2.2, docs/online-estimator.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

from gateway.estimate.swarm import ALMERIA_OFFLINE
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model

DEFAULT_ITERATIONS = 50
"""RSBA iterations per estimation. The thesis does not print its online count. In boxes of
±0.2–10 % around the current values, 50 iterations × 20 bats (1000 virtual-model runs) already
give the error of 100 (docs/online-estimator.md, "Iterations") at half the time per step."""


@dataclass(frozen=True)
class GroupSettings:
    """Settings of one estimation group (thesis §IV.2.2.2).

    ``parameters``: the names searched (resolved: never empty); ``window``: n past samples
    re-simulated; ``every``: period in model steps; ``iterations``/``bats``: RSBA budget;
    ``prior``: weight λ [°C² or (W m-2)²] of the pull toward the starting values, added to the
    window MSE as λ mean_j ((θ_j - θ0_j)/(hi_j - lo_j))² (0 = the thesis's estimator).
    """

    output: str
    parameters: tuple[str, ...]
    window: int
    every: int
    iterations: int = DEFAULT_ITERATIONS
    bats: int = ALMERIA_OFFLINE.bats
    prior: float = 0.0


def online_settings(
    model: Model, gh: Greenhouse | None = None, overrides: Mapping[str, Mapping[str, float]] | None = None
) -> tuple[GroupSettings, ...]:
    """The model's estimation groups (``Model.online``) with the greenhouse's ``[online.<output>]``
    settings and then ``overrides`` applied on top.

    A group whose ``parameters`` is empty takes every parameter no other group claims.
    """
    claimed = {n for g in model.online for n in g.parameters}
    groups = []
    for g in model.online:
        names = g.parameters or tuple(n for n in model.names if n not in claimed)
        unknown = [n for n in names if n not in model.names]
        if unknown:
            raise ValueError(f"{model.name}: online group '{g.output}' names unknown {unknown}")
        s = GroupSettings(g.output, names, g.window, g.every)
        for source in (gh.online if gh is not None else {}, overrides or {}):
            table = dict(source.get(g.output, {}))
            bad = [k for k in table if k not in ("window", "every", "iterations", "bats", "prior")]
            if bad:
                raise ValueError(f"online.{g.output}: unknown setting(s) {', '.join(bad)}")
            for key in ("window", "every", "iterations", "bats"):
                if key in table:
                    value = float(table[key])
                    if value != int(value):  # 2.7 samples is a typo, not 2
                        raise ValueError(f"online.{g.output}.{key} must be a whole number, got {table[key]}")
                    table[key] = int(value)
                    if table[key] < (2 if key == "bats" else 1):
                        raise ValueError(f"online.{g.output}.{key} must be positive, got {table[key]}")
            if "prior" in table:
                table["prior"] = float(table["prior"])
                if not table["prior"] >= 0:
                    raise ValueError(f"online.{g.output}.prior must be >= 0, got {table['prior']}")
            s = replace(s, **table)
        groups.append(s)
    known = {g.output for g in model.online}
    for source in (gh.online if gh is not None else {}, overrides or {}):
        extra = [k for k in source if k not in known]
        if extra:
            raise ValueError(
                f"online.{extra[0]}: the '{model.name}' model has no such estimation group "
                f"(groups: {', '.join(sorted(known))})"
            )
    return tuple(groups)

"""A saved estimator state carried over to another model (issue 10: ``prototype`` ↔
``prototype+vent_control``).

A greenhouse whose ``model =`` changes finds, at the gateway's start, a snapshot
(``OnlineEstimator.snapshot``) of the other model. Its parameters that the new model has with
the same name *and unit* (the same quantity: the almeria model's ``c_loss`` [m3 s-1] is not the
prototype's [m s-1]) keep their adapted values; the new model's other parameters start at their
initial values (the estimator's ``theta0``: the params file's or the middle of the hard box, where
a new estimator would start); the saved model's other parameters are dropped. Everything else
in the snapshot (the window of drivers, the random generator, counters, the cloud tracker, the
forecaster's filter, ARX, combiner and correction) does not depend on the model's parameters and
is kept; the parameter vectors inside it (``theta``, ``theta0``, ``theta_before``, the disturbance
filter's last θ) are mapped alike. Models with no parameter in common are not migrated
(``ValueError``: the caller starts anew, as before).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import build_model
from gateway.model.model import Model


@dataclass(frozen=True)
class Migration:
    """What a migration did, for the one log line that names it."""

    source: str
    target: str
    kept: tuple[str, ...]
    added: tuple[tuple[str, float], ...]  # (name, the initial value it starts from)
    dropped: tuple[str, ...]

    def describe(self) -> str:
        added = ", ".join(f"{n} = {v:g}" for n, v in self.added) or "none"
        return (f"saved estimator state migrated from model {self.source!r} to {self.target!r}: "
                f"kept {', '.join(self.kept)} (their adapted values); new at their initial "
                f"values: {added}; dropped: {', '.join(self.dropped) or 'none'}")


def matching(source: Model, target: Model) -> list[str]:
    """The target's parameter names that the source has with the same unit (the same quantity)."""
    units = {p.name: p.unit for p in source.parameters}
    return [p.name for p in target.parameters if units.get(p.name) == p.unit]


def _mapper(names: Sequence[str], target: Model, theta0: np.ndarray):
    """θ of the saved ``names`` → θ of ``target``: matching values copied, the rest ``theta0``."""
    src = {n: i for i, n in enumerate(names)}
    pairs = [(target.index(n), src[n]) for n in target.names if n in src]

    def carry(theta: Sequence[float]) -> list[float]:
        old = np.asarray(theta, dtype=float)
        if old.shape != (len(names),):
            raise ValueError(f"saved estimator state: a parameter vector of {old.shape} values "
                             f"for {len(names)} names")
        new = np.array(theta0, dtype=float)
        for j, i in pairs:
            new[j] = old[i]
        return new.tolist()

    return carry


def migrate_state(snap: Mapping[str, Any], target: Model, gh: Greenhouse,
                  theta0: np.ndarray) -> tuple[dict[str, Any], Migration]:
    """``snap`` (a snapshot of another model's estimator) as a snapshot of ``target``'s, and what
    was kept, added and dropped. ValueError when the saved model is unknown or shares no
    parameter with ``target`` (nothing to carry)."""
    source = build_model(str(snap.get("model")), gh)  # ValueError for an unknown model
    names = [str(n) for n in snap.get("names", [])]
    if names != source.names:
        raise ValueError(f"saved estimator state: names {names} are not model "
                         f"{source.name!r}'s {source.names}")
    kept = [n for n in matching(source, target) if n in names]
    if not kept:
        raise ValueError(f"model {source.name!r} shares no parameter with {target.name!r}")
    carry = _mapper(names, target, theta0)
    out = copy.deepcopy(dict(snap))
    out["model"], out["names"] = target.name, list(target.names)
    for key in ("theta", "theta0"):
        out[key] = carry(snap[key])
    out["theta_before"] = [carry(t) for t in snap.get("theta_before", [])]
    fc = out.get("forecaster") or {}
    dist = fc.get("disturbance") or {}
    if dist.get("prev") is not None:  # the filter's last step is made with the last θ
        dist["prev"][1] = carry(dist["prev"][1])
    added = tuple((n, float(theta0[target.index(n)])) for n in target.names if n not in kept)
    dropped = tuple(n for n in names if n not in kept)
    return out, Migration(source.name, target.name, tuple(kept), added, dropped)

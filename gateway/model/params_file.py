"""Calibrated parameters file (``calibrate --out``): TOML with ``model = "..."`` and ``[params]``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model.model import Model
from gateway.tomlfile import read_toml


class ParamsFileError(ValueError):
    """A parameters file that cannot be used; the message names the file and the key."""


def read_params(path: str | Path, model: Model, gh: Greenhouse | None = None) -> np.ndarray:
    """The parameter vector of ``model``: its defaults for greenhouse ``gh`` (its overrides and
    cover transmission, ``Model.defaults``) with the file's ``[params]`` on top, so a key the
    file lacks starts where it would without a file."""
    raw = read_toml(path, ParamsFileError, "parameters file")
    params = raw.get("params")
    if not isinstance(params, dict):
        raise ParamsFileError(f"{path}: no [params] table")
    if raw.get("model") not in (None, model.name):
        raise ParamsFileError(f"{path}: parameters are for model '{raw.get('model')}', not '{model.name}'")
    unknown = [k for k in params if k not in model.names]
    if unknown:
        raise ParamsFileError(f"{path}: unknown parameter(s) {', '.join(unknown)} for model {model.name}")
    theta = model.defaults(gh)
    for k, v in params.items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ParamsFileError(f"{path}: params.{k} must be a finite number")
        theta[model.index(k)] = float(v)
    return theta


@dataclass(frozen=True)
class OutOfBox:
    """A starting value outside its hard box. The online estimator clips its starting values
    into the box without a word (gateway/estimate/online.py), so a hand-edited file, or one
    calibrated before the greenhouse's [parameters] bounds were narrowed, would otherwise run
    on a value nobody wrote; this says which."""

    name: str
    value: float  # the file's
    lower: float
    upper: float

    @property
    def used(self) -> float:
        """The value the estimator starts from: the file's, clipped into [lower, upper]."""
        return min(max(self.value, self.lower), self.upper)

    def describe(self, path: str | Path, uses: str = "the estimator uses") -> str:
        """One line naming the file, the key, the box and the value used (``uses`` says who)."""
        return (f"{path}: params.{self.name} = {self.value:g} is outside its hard box "
                f"[{self.lower:g}, {self.upper:g}] (the model's, or the greenhouse's [parameters] "
                f"bounds): {uses} {self.used:g}")


def outside_box(theta: np.ndarray, model: Model, gh: Greenhouse) -> list[OutOfBox]:
    """The starting values of ``theta`` (from :func:`read_params`) outside the hard box of
    ``model`` in ``gh``: the one check behind ``replay --params``, ``run --check`` and the live
    service's start. Not an error: the estimator runs on the clipped value."""
    lo, hi = model.bounds(gh)
    return [OutOfBox(model.names[j], float(theta[j]), float(lo[j]), float(hi[j]))
            for j in np.flatnonzero((theta < lo) | (theta > hi))]

"""Calibrated parameters file (``calibrate --out``): TOML with ``model = "..."`` and ``[params]``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gateway.model.model import Model
from gateway.tomlfile import read_toml


class ParamsFileError(ValueError):
    """A parameters file that cannot be used; the message names the file and the key."""


def read_params(path: str | Path, model: Model) -> np.ndarray:
    """The parameter vector of ``model``: its defaults with the file's ``[params]`` on top."""
    raw = read_toml(path, ParamsFileError, "parameters file")
    params = raw.get("params")
    if not isinstance(params, dict):
        raise ParamsFileError(f"{path}: no [params] table")
    if raw.get("model") not in (None, model.name):
        raise ParamsFileError(f"{path}: parameters are for model '{raw.get('model')}', not '{model.name}'")
    unknown = [k for k in params if k not in model.names]
    if unknown:
        raise ParamsFileError(f"{path}: unknown parameter(s) {', '.join(unknown)} for model {model.name}")
    theta = model.defaults()
    for k, v in params.items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ParamsFileError(f"{path}: params.{k} must be a finite number")
        theta[model.index(k)] = float(v)
    return theta

"""Shared set-ups of the diagnosis's unit tests: a sunny sine-weather series and the prototype
base in its structured form."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gateway.diagnose.structure import structure
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.series import Series


def sine_series(n: int = 2880, step: int = 60) -> Series:
    """``n`` rows at ``step`` s of daily sine weather (T_out 5–15 °C, a 600 W m-2 sun, 2 m s-1
    wind) with the inside reading a constant 12 °C (the tests put their own in)."""
    t = np.arange(n) * step
    day = (t % 86400) / 86400
    cols = {"t_out": 10 + 5 * np.sin(2 * np.pi * (day - 0.3)), "rh_out": np.full(n, 70.0),
            "i_glob": np.maximum(0, 600 * np.sin(2 * np.pi * (day - 0.25))), "wind": np.full(n, 2.0),
            "rh_in": np.full(n, 60.0), "t_in": np.full(n, 12.0)}
    return Series((np.datetime64("2020-01-01T00:00:00") + t.astype("timedelta64[s]")), float(step), cols)


def prototype_bases(store: bool = False):
    """(greenhouse, the prototype base, its structured form); the base integrated as the
    structured form is (the zero-order hold its coarsened inputs are built for,
    structure.Structured.advance)."""
    gh = load_greenhouse("biskra-prototype")
    m = structure(build_model("prototype", gh), gh, store)
    base = replace(build_model("prototype", gh), integration=m.integration)
    return gh, base, m

"""A fingerprint of the code that computes the sensor's inputs, stored in the model's metadata.

The sensor reads the adaptive model's heat fluxes; a change to the model layer (a flux term,
the sky temperature, the step) changes them, and a network trained before it then reads inputs
the code no longer produces — silently, since names, units and delays still match. Training
writes ``code_probe`` (what this module computes) into the ONNX metadata; the shipped-model test
recomputes it with the running code and fails, naming the quantity, when they differ.

The probe: three deterministic hours of drivers (fixed UTC start, smooth sinusoids, the
greenhouse's site), the model's published parameters; recorded every 15 minutes: each flux term
[W m-2] along the measured T_in, the sky temperature [°C], and the one-step-ahead T_in [°C] of
the model's integrator (gateway/model/step.py). The online estimator (RSBA) is not probed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import build_model
from gateway.model.drivers import prepare_drivers
from gateway.series import Series

PROBE_START = "2020-04-10T08:00:00"
PROBE_MINUTES = 180
PROBE_EVERY = 15
RTOL = 1e-6


def probe_series() -> Series:
    """Three hours of made-up but plausible kit data on a one-minute grid (no vents)."""
    n = PROBE_MINUTES + 1
    k = np.arange(n, dtype=float)
    w = 2.0 * math.pi * k / 240.0
    cols = {
        "t_out": 16.0 + 4.0 * np.sin(w),
        "t_in": 21.0 + 6.0 * np.sin(w + 0.3),
        "rh_out": 60.0 - 10.0 * np.sin(w),
        "rh_in": 75.0 - 8.0 * np.sin(w + 0.2),
        "i_glob": 350.0 + 250.0 * np.sin(w) + 80.0 * np.sin(7.0 * w),
        "wind": 2.5 + 1.5 * np.cos(3.0 * w),
        "t_soil": 18.0 + 1.0 * np.sin(w - 0.5),
    }
    time = np.datetime64(PROBE_START, "s") + (60 * np.arange(n)).astype("timedelta64[s]")
    return Series(time, 60.0, cols, "<vsensor probe>")


def code_probe(kind: str, gh: Greenhouse) -> dict[str, list[float]]:
    """The probe's values for the ``kind`` model (JSON-ready lists of floats)."""
    model = build_model(kind, gh)
    x = prepare_drivers(probe_series(), gh)
    theta = model.defaults(gh)
    rows = slice(PROBE_EVERY, PROBE_MINUTES + 1, PROBE_EVERY)
    out = {f"flux.{name}": np.asarray(v)[rows]
           for name, v in model.fluxes(theta, x, x["t_in"]).items()}
    out["t_sky"] = x["t_sky"][rows]
    out["one_step_t_in"] = model.one_step(theta[None, :], x, gh, 60.0)[0, rows]
    n = len(range(*rows.indices(PROBE_MINUTES + 1)))
    return {k: [float(f"{v:.10g}") for v in np.broadcast_to(np.asarray(a, float), (n,))]
            for k, a in out.items()}


def probe_differences(stored: Mapping[str, list[float]], kind: str, gh: Greenhouse) -> list[str]:
    """What differs between a model's stored probe and what the running code computes
    (empty when they agree to ``RTOL``)."""
    now = code_probe(kind, gh)
    diffs = []
    for key in sorted(set(stored) | set(now)):
        if key not in stored or key not in now:
            diffs.append(f"{key}: {'not in the model' if key not in stored else 'no longer computed'}")
            continue
        a, b = np.asarray(stored[key], float), np.asarray(now[key], float)
        if a.shape != b.shape or not np.allclose(a, b, rtol=RTOL, atol=1e-9):
            i = int(np.argmax(np.abs(a - b))) if a.shape == b.shape else 0
            diffs.append(f"{key}: trained with {a[i]:.6g}, the code now gives {b[i]:.6g} "
                         f"(minute {(i + 1) * PROBE_EVERY} of the probe)")
    return diffs

"""The closed loop of a NARX (IV.55): each estimate is fed back as a past output.

``y(k) = f(u(k), …, u(k-5), y(k-1), …, y(k-5))`` with ``u`` the filtered inputs and ``y`` the
sensor's own past (clamped) outputs, never a measured flow: the deployed sensor has none. One
function for every batch user (training metrics, baselines, tests); ``VentSensor.step`` runs the
same recurrence one step at a time, and a test holds the two equal.

``bounds`` (optional, both): every filtered input clamped to its padded training range
(:func:`padded_ranges`, the bounds beyond which the runtime flags it out of range) before it
enters the network, so the network is never asked to extrapolate (docs/vsensor.md, tenth pass).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gateway.vsensor.features import INPUT_DELAYS, OUTPUT_DELAYS

RANGE_MARGIN = 0.02
"""An input counts as outside the training range beyond min − 2 % or max + 2 % of its span."""
Bounds = tuple[np.ndarray, np.ndarray]
"""(lo, hi), each (F,): the padded training range of every filtered input."""
Predict = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``predict(u, y_past)``: u (N, len(INPUT_DELAYS), F) with u[:, d] the inputs at k - d;
y_past (N, len(OUTPUT_DELAYS)) with y_past[:, j] the output at k - 1 - j → flows (N,)."""


def padded_ranges(ranges: np.ndarray) -> Bounds:
    """(lo, hi) of the training ranges (F, 2) widened by ``RANGE_MARGIN`` of their span: the
    runtime's out-of-range flag and, when asked, the input clamp (one arithmetic for both)."""
    r = np.asarray(ranges, dtype=float)
    lo, hi = r[:, 0], r[:, 1]
    pad = RANGE_MARGIN * np.maximum(hi - lo, 1e-9)
    return lo - pad, hi + pad


def fill_missing(inputs: np.ndarray, fill: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inputs with every NaN replaced by ``fill`` (per feature), and the mask of replaced cells."""
    missing = ~np.isfinite(inputs)
    return np.where(missing, fill, inputs), missing


def closed_loop(predict: Predict, inputs: np.ndarray, upper: np.ndarray, y0: float,
                histories: int = 1, bounds: Bounds | None = None) -> np.ndarray:
    """Run the NARX over ``inputs`` (N, T, F) (no NaN: see :func:`fill_missing`) in closed loop.

    ``upper`` (N, T) is the physical upper limit of the flow at each step (``FlowLimits.upper``);
    every output is clipped to [0, upper]. Before the first step the past inputs repeat the
    first row and the past outputs are ``y0`` (the sensor knows no history when it starts).
    ``histories`` K > 1: an ensemble whose members each hear their own past outputs; ``predict``
    takes y_past (N, K, 5) and gives (N, K), each member's output is held (non-finite) and
    clipped on its own, the flow is their mean.
    ``bounds``: each input clipped to [lo, hi] first (in-range values untouched, bit for bit).
    Returns the flows (N, T) [m3 s-1]. Vectorised over the N series: one call per step.
    """
    if bounds is not None:
        inputs = np.clip(inputs, bounds[0], bounds[1])
    n, t_len, n_f = inputs.shape
    d_in = max(INPUT_DELAYS) + 1
    d_out = max(OUTPUT_DELAYS)
    u = np.concatenate([np.repeat(inputs[:, :1], d_in - 1, axis=1), inputs], axis=1)
    k_h = int(histories)
    y_past = np.full((n, k_h, d_out), float(y0))
    out = np.empty((n, t_len))
    for k in range(t_len):
        window = u[:, k : k + d_in][:, ::-1]  # [:, d] = inputs at k - d
        yp = y_past if k_h > 1 else y_past[:, 0]
        y = np.asarray(predict(window, yp), dtype=float).reshape(n, k_h)
        y = np.where(np.isfinite(y), y, y_past[:, :, 0])  # a non-finite output holds the last one
        y = np.clip(y, 0.0, upper[:, k, None])
        out[:, k] = y.mean(axis=1)
        y_past = np.concatenate([y[:, :, None], y_past[:, :, :-1]], axis=2)
    return out

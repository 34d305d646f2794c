"""Radiation evidence for a cover transmission change (docs/effects.md, "The effects").

When the model has the III.35 radiation sub-model ``i_in = c_tsw i_glob`` and the data the
measured inside radiation, a transmission change shows on ``i_in`` directly: its start and
size are fitted there (least squares for every τ at once, as the thesis fits c_tsw on i_in
before the temperature), and the ``i_in`` part of ΔBIC counts in its evidence, so the
temperature cannot trade it for another effect.
"""

from __future__ import annotations

import numpy as np

from gateway.diagnose.bic import delta_bic, effective_samples
from gateway.diagnose.evidence import Evidence
from gateway.model.model import Model
from gateway.model.terms import SUN_THRESHOLD


def measures_radiation(model: Model, x: dict[str, np.ndarray]) -> bool:
    """Does the model have a radiation sub-model (III.35) and the data the inside radiation?"""
    return model.radiation is not None and "i_in" in x and int(np.isfinite(x["i_in"]).sum()) > 10


def _sunlit(x: dict[str, np.ndarray], z: np.ndarray, segments: list[tuple[int, int]]) -> np.ndarray:
    use = np.zeros(len(z), dtype=bool)
    for a, b in segments:
        use[a:b] = True
    return use & np.isfinite(x["i_in"]) & np.isfinite(z) & (x["i_glob"] > SUN_THRESHOLD)


def _c_tsw(model: Model) -> int:
    """Index of the radiation sub-model's parameter (c_tsw) in ``model``'s vector."""
    if model.radiation is None:
        raise ValueError(f"{model.name}: a transmission change needs the radiation sub-model "
                         "(i_in = c_tsw i_glob, III.35)")
    return model.index(model.radiation.parameter.name)


def radiation_change(model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
                     segments: list[tuple[int, int]], first: float,
                     last: float = np.inf) -> tuple[float, float]:
    """Start τ [s] and relative size d of a step change of the cover transmission seen on the
    measured inside radiation: ``i_in = c_tsw (1 + d [t ≥ τ]) i_glob`` (III.35), least squares
    over sunlit samples of ``segments``, every ``first`` ≤ τ ≤ ``last`` at once through reverse
    cumulative sums."""
    j = _c_tsw(model)
    z = theta[j] * x["i_glob"]  # predicted i_in
    r = x["i_in"] - z
    ok = _sunlit(x, z, segments) & np.isfinite(r)
    r, z = np.where(ok, r, 0.0), np.where(ok, z, 0.0)
    s_rz = np.cumsum((r * z)[::-1])[::-1]  # Σ_{t ≥ τ}
    s_zz = np.cumsum((z * z)[::-1])[::-1]
    gain = np.where(s_zz > 0, s_rz**2 / np.where(s_zz > 0, s_zz, 1.0), 0.0)
    gain[(x["_index"] < first) | (x["_index"] > last)] = -1.0
    k = int(np.argmax(gain))
    while k + 1 < len(gain) and gain[k + 1] >= gain[k] * (1.0 - 1e-9):  # latest of equals
        k += 1
    d = float(s_rz[k] / s_zz[k]) if s_zz[k] > 0 else 0.0
    return float(x["_index"][k]), d


def radiation_bic_delta(model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
                        segments: list[tuple[int, int]], tau: float, d: float) -> float:
    """ΔBIC of a transmission change (τ, d) on the measured inside radiation (III.35) over the
    sunlit samples of ``segments``: the second output a change of c_tsw has to explain."""
    j = _c_tsw(model)
    z = theta[j] * x["i_glob"]
    ok = _sunlit(x, z, segments)
    if ok.sum() < 10:
        return 0.0
    r0 = (x["i_in"] - z)[ok]
    r1 = (x["i_in"] - z * (1.0 + d * (x["_index"] >= tau)))[ok]
    n_e = effective_samples(int(ok.sum()), float(x["_index"][1] - x["_index"][0]))
    return delta_bic(float(r1 @ r1), float(r0 @ r0), n_e, 2)


class RadiationEvidence(Evidence):
    """A cover transmission change on the measured inside radiation (when there is one)."""

    def fits_start(self, model, x) -> bool:
        return measures_radiation(model, x)

    def scan(self, model, x, theta, segments, first, last):
        return radiation_change(model, x, theta, segments, first, last)

    def delta_bic(self, model, x, theta, segments, tau, amp) -> float:
        if not measures_radiation(model, x):
            return 0.0
        return radiation_bic_delta(model, x, theta, segments, tau, amp)

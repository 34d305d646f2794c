"""A second output an effect must also explain (beside the inside temperature).

Some effects change more than the heat balance: a cover transmission change shows on the
measured inside radiation (radiation.py), added air exchange dilutes the night-time vapour
excess (humidity.py). Each effect of the library carries one :class:`Evidence`; the search
asks it, never the effect's name, whether and how that second output speaks.
"""

from __future__ import annotations

import numpy as np

from gateway.model.model import Model


class Evidence:
    """No second output: the temperature decides alone."""

    def fits_start(self, model: Model, x: dict[str, np.ndarray]) -> bool:
        """Does this output fix the effect's start and amplitude by itself (then the scan takes
        them from :meth:`scan` and the amplitude is held in the joint refit)?"""
        return False

    def scan(self, model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
             segments: list[tuple[int, int]], first: float, last: float) -> tuple[float, float]:
        """(τ [s], amplitude) fitted on this output over ``segments``, ``first`` ≤ τ ≤ ``last``."""
        raise NotImplementedError

    def delta_bic(self, model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
                  segments: list[tuple[int, int]], tau: float, amp: float) -> float:
        """ΔBIC of the effect (τ, amplitude) on this output over ``segments`` (0: silent)."""
        return 0.0

    def profile(self, model: Model, x: dict[str, np.ndarray], theta: np.ndarray,
                segments: list[tuple[int, int]], taus: np.ndarray, amps: np.ndarray) -> np.ndarray:
        """:meth:`delta_bic` for every (τ, amplitude) of a τ scan: the second output's share of
        the scan's profile, so a start the temperature leaves open is placed where this output
        shows the change."""
        return np.array([self.delta_bic(model, x, theta, segments, float(t), float(a))
                         for t, a in zip(taus, amps, strict=True)])


NONE = Evidence()

"""The radiation sub-model ``i_in = c_tsw i_glob`` (III.35) and its one fit.

c_tsw is fitted on the measured inside radiation, on the sunlit samples only (outside radiation
> 5 W m-2, §IV.2.1.2): the offline calibration (gateway/estimate/calibrate.py), the online
estimator (every 20 minutes on the last 60, gateway/estimate/online.py) and the diagnosis all
call :meth:`RadiationSubmodel.fit`. The model is linear in c_tsw, so the least-squares value is
closed form; in a box [lo, hi] the minimum of the one-dimensional quadratic is that value
clipped (what a swarm search of the box converges to).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from gateway.model.terms import SUN_THRESHOLD, Parameter


@dataclass(frozen=True)
class RadiationFit:
    """Result of :meth:`RadiationSubmodel.fit`: the value, its cost (mean squared error
    [(W m-2)²] plus the prior's pull) and the number of sunlit pairs it used."""

    value: float
    cost: float
    pairs: int


@dataclass(frozen=True)
class RadiationSubmodel:
    """Inside short-wave radiation ``i_in = c_tsw * i_glob`` (III.35), fitted on measured i_in."""

    parameter: Parameter
    equation: str = "III.35"

    def predict(self, c_tsw: np.ndarray, x: Mapping[str, np.ndarray]) -> np.ndarray:
        """i_in [W m-2] for c_tsw of shape (P, 1) → (P, T)."""
        return c_tsw * x["i_glob"]

    def pairs(self, x: Mapping[str, np.ndarray], span: tuple[int, int] | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
        """(i_glob, i_in) of the sunlit samples of rows ``span`` where both are measured."""
        if "i_in" not in x:
            return np.zeros(0), np.zeros(0)
        a, b = span if span is not None else (0, len(x["i_glob"]))
        i_out, i_in = np.asarray(x["i_glob"][a:b], float), np.asarray(x["i_in"][a:b], float)
        ok = np.isfinite(i_out) & np.isfinite(i_in) & (i_out > SUN_THRESHOLD)
        return i_out[ok], i_in[ok]

    def fit(
        self,
        x: Mapping[str, np.ndarray],
        span: tuple[int, int] | None = None,
        bounds: tuple[float, float] | None = None,
        min_pairs: int = 10,
        prior: tuple[float, float, float] | None = None,
    ) -> RadiationFit | None:
        """Least squares of the measured i_in on i_glob over the sunlit samples of ``span``.

        ``bounds``: the box searched (default: the parameter's hard bounds); ``prior``:
        ``(lambda, c0, width)`` adds ``lambda ((c - c0)/width)²`` to the mean squared error (the
        online estimator's pull toward its start). None when fewer than ``min_pairs`` sunlit
        pairs are measured.
        """
        i_out, i_in = self.pairs(x, span)
        n = len(i_out)
        if n < max(min_pairs, 1):
            return None
        lo, hi = bounds if bounds is not None else (self.parameter.lower, self.parameter.upper)
        sxx = float(np.mean(i_out * i_out))
        sxy = float(np.mean(i_in * i_out))
        lam, c0, width = prior if prior is not None else (0.0, 0.0, 1.0)
        w = lam / (width * width)
        c = float(np.clip((sxy + w * c0) / (sxx + w), lo, hi))
        cost = float(np.mean((c * i_out - i_in) ** 2) + w * (c - c0) ** 2)
        return RadiationFit(c, cost, n)

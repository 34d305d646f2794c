"""The live forecasts of one greenhouse: replay's ``adaptive``, ``adaptive_kf`` or ``combined``.

- ``adaptive``: the model run forward with the parameters in force from the measured T_in;
- ``adaptive_kf``: the same from the disturbance filter's state (gateway/estimate/disturbance.py);
- ``combined`` (default): ``adaptive_kf`` and the RLS ARX baseline (gateway/estimate/arx.py, run
  live on the same rows) weighted by their recent skill (gateway/estimate/combination.py).

Per model step, call ``update`` after the estimator's update, then ``forecasts`` when the step
makes forecasts (a step that makes none is recorded as such at the next ``update``). The state
goes into the estimator's saved snapshot (``snapshot``/``restore``): a restarted gateway resumes
the identical run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from gateway.estimate import arx as arx_baseline
from gateway.estimate import combination, disturbance
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model

KINDS = ("adaptive", "adaptive_kf", "combined")
PARTS = ("adaptive_kf", "arx")
"""The combined forecast's parts, in the combiner's order (the first alone until both have
met targets)."""


class LiveForecaster:
    """Forecasts of T_in ``horizons`` model steps ahead, of the ``kind`` in ``KINDS``."""

    def __init__(self, model: Model, gh: Greenhouse, dt: float, horizons: Sequence[int],
                 kind: str = "combined") -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown forecast {kind!r} (known: {', '.join(KINDS)})")
        self.model, self.gh, self.dt, self.kind = model, gh, dt, kind
        self.horizons = tuple(horizons)
        self._start()

    def _start(self) -> None:
        kind, dt = self.kind, self.dt
        self.kf = disturbance.LiveFilter(self.model, self.gh, dt) if kind != "adaptive" else None
        self.arx = arx_baseline.Rls() if kind == "combined" else None
        window = max(int(round(combination.WINDOW_S / dt)), 1)
        self.comb = (combination.LiveCombiner(PARTS, self.horizons, window)
                     if kind == "combined" else None)
        self._arx_prev: tuple[np.ndarray, float] | None = None  # φ and T_in of the last step
        self._added = True  # the last step's forecasts were handed to the combiner

    def update(self, row: Mapping[str, float], theta: np.ndarray) -> None:
        """The drivers at t (the estimator's ``last_row``) and the parameters in force at t."""
        if self.kf is not None:
            self.kf.update(row, theta)
        if self.arx is None or self.comb is None:
            return
        if not self._added:
            self.comb.add(None)  # the last step made no forecasts
        t_in = float(row.get("t_in", math.nan))
        x = {k: np.array([v], dtype=float) for k, v in row.items()}
        try:
            phi = arx_baseline.regressors(x, np.array([t_in]), 0)[0]
        except KeyError:  # a driver the baseline needs is not there
            phi = np.full(len(arx_baseline.REGRESSORS), math.nan)
        if self._arx_prev is not None:
            self.arx.update(self._arx_prev[0], t_in - self._arx_prev[1])
        self._arx_prev = (phi, t_in)
        self.comb.observe(t_in)
        self._added = False

    def forecasts(self, theta: np.ndarray, x: Mapping[str, np.ndarray],
                  horizons: Sequence[int]) -> dict[int, float]:
        """T_in ``h`` steps after now for each horizon, from drivers ``x`` whose row 0 is now
        (the outlook's block); NaN where a forecast cannot be made."""
        rows, out = np.array([0]), {}
        start = self.kf.estimate() if self.kf is not None else None
        made: dict[int, dict[str, float]] = {}
        for h in horizons:
            if start is None:
                out[h] = float(self.model.forecast(theta[None, :], x, self.gh, self.dt, rows, h)[0])
                continue
            kf = float(disturbance.forecast(self.model, theta[None, :], x, self.gh, self.dt, rows,
                                            h, np.array([start[0]]), np.array([start[1]]),
                                            self.kf.settings)[0])
            out[h] = kf
            if self.arx is not None and self.comb is not None:
                lin = arx_baseline.ArxResult(self.arx.theta[None, :], np.zeros(0), self.arx.updates)
                arx = float(lin.forecast(x, rows, h)[0])
                made[h] = {"adaptive_kf": kf, "arx": arx}
                mixed = combination.mix({"adaptive_kf": kf, "arx": arx}, self.comb.weights(h))
                if math.isfinite(mixed):
                    out[h] = mixed
        if self.comb is not None and not self._added:
            self.comb.add(made)
            self._added = True
        return out

    def reset(self) -> None:
        """After a long gap: the filter, the pending forecasts and the ARX's last pair go; the
        ARX's parameters and the combiner's errors are kept (like the estimator's parameters)."""
        if self.kf is not None:
            self.kf.reset()
        if self.comb is not None:
            self.comb.drop_pending()
        self._arx_prev, self._added = None, True

    def snapshot(self) -> dict:
        prev = self._arx_prev
        return {"kind": self.kind,
                "disturbance": self.kf.snapshot() if self.kf is not None else None,
                "arx": self.arx.snapshot() if self.arx is not None else None,
                "arx_prev": None if prev is None else [prev[0].tolist(), prev[1]],
                "combination": self.comb.snapshot() if self.comb is not None else None,
                "added": self._added}

    def restore(self, snap: Mapping | None) -> None:
        """Continue from a ``snapshot``; None or another kind's state: start afresh."""
        self._start()
        if not snap or snap.get("kind") != self.kind:
            return
        if self.kf is not None:
            self.kf.restore(snap["disturbance"])
        if self.arx is not None and snap.get("arx"):
            self.arx.restore(snap["arx"])
        if self.comb is not None:
            self.comb.restore(snap["combination"])
        prev = snap.get("arx_prev")
        self._arx_prev = None if prev is None else (np.asarray(prev[0], float), float(prev[1]))
        self._added = bool(snap.get("added", True))

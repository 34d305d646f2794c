"""The live forecasts of one greenhouse: replay's ``adaptive``, ``adaptive_kf``, ``combined`` or
``corrected``.

- ``adaptive``: the model run forward with the parameters in force from the measured T_in;
- ``adaptive_kf``: the same from the disturbance filter's state (gateway/estimate/disturbance.py);
- ``combined``: ``adaptive_kf`` and the RLS ARX baseline (gateway/estimate/arx.py, run
  live on the same rows) weighted by their recent skill (gateway/estimate/combination.py);
- ``corrected`` (default): ``combined`` with its online error correction, the ARX stacked
  (gateway/estimate/correction.py).

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
from gateway.estimate import combination, correction, disturbance
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model

KINDS = ("adaptive", "adaptive_kf", "combined", "corrected")
PARTS = ("adaptive_kf", "arx")
"""The combined forecast's parts, in the combiner's order (the first alone until both have
met targets)."""
UPGRADES = {"corrected": ("combined",)}
"""A kind whose saved state another kind continues (its parts are the same)."""


class LiveForecaster:
    """Forecasts of T_in ``horizons`` model steps ahead, of the ``kind`` in ``KINDS``."""

    def __init__(self, model: Model, gh: Greenhouse, dt: float, horizons: Sequence[int],
                 kind: str = "corrected") -> None:
        if kind not in KINDS:
            raise ValueError(f"unknown forecast {kind!r} (known: {', '.join(KINDS)})")
        self.model, self.gh, self.dt, self.kind = model, gh, dt, kind
        self.horizons = tuple(horizons)
        self._start()

    def _start(self) -> None:
        kind, dt = self.kind, self.dt
        self.kf = disturbance.LiveFilter(self.model, self.gh, dt) if kind != "adaptive" else None
        mixed = kind in ("combined", "corrected")
        self.arx = arx_baseline.Rls() if mixed else None
        window = max(int(round(combination.WINDOW_S / dt)), 1)
        self.comb = combination.LiveCombiner(PARTS, self.horizons, window) if mixed else None
        self.corr = correction.Corrector(self.horizons, dt) if kind == "corrected" else None
        self._row: dict[str, float] = {}  # the correction's drivers now
        self._arx_prev: tuple[np.ndarray, float] | None = None  # φ and T_in of the last step
        self._added = True  # the last step's forecasts were handed to the combiner

    def update(self, row: Mapping[str, float], theta: np.ndarray,
               time: np.datetime64 | None = None) -> None:
        """The drivers at t (the estimator's ``last_row``), the parameters in force at t and t
        itself (UTC; the correction's hour of the day, ``corrected`` only)."""
        if self.kf is not None:
            self.kf.update(row, theta)
        if self.arx is None or self.comb is None:
            return
        if not self._added:
            self.comb.add(None)  # the last step made no forecasts
            if self.corr is not None:
                self.corr.add()
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
        if self.corr is not None:
            self.corr.observe(t_in)
            hour = math.nan if time is None else float(correction.hour_of_day(np.array([time]))[0])
            self._row = {"i_glob": float(row.get("i_glob", math.nan)),
                         "t_out": float(row.get("t_out", math.nan)), "hour": hour, "t_in": t_in}
        self._added = False

    def forecasts(self, theta: np.ndarray, x: Mapping[str, np.ndarray],
                  horizons: Sequence[int]) -> dict[int, float]:
        """T_in ``h`` steps after now for each horizon, from drivers ``x`` whose row 0 is now
        (the outlook's block); NaN where a forecast cannot be made."""
        rows, out = np.array([0]), {}
        start = self.kf.estimate() if self.kf is not None else None
        made: dict[int, dict[str, float]] = {}
        # one run to the longest horizon, read at each (the same numbers as a run per horizon)
        if start is None or self.kf is None:  # start is None without a filter
            runs = self.model.forecast_each(theta[None, :], x, self.gh, self.dt, rows, horizons)
        else:
            runs = disturbance.forecast_each(self.model, theta[None, :], x, self.gh, self.dt,
                                             rows, horizons, np.array([start[0]]),
                                             np.array([start[1]]), self.kf.settings)
        linear: dict[int, np.ndarray] = {}
        if start is not None and self.kf is not None and self.arx is not None and self.comb is not None:
            lin = arx_baseline.ArxResult(self.arx.theta[None, :], np.zeros(0), self.arx.updates)
            linear = lin.forecast_each(x, rows, horizons)  # one run, read at each horizon
        for h in horizons:
            out[h] = kf = float(runs[h][0])
            if start is None or self.kf is None:
                continue
            if self.arx is not None and self.comb is not None:
                arx = float(linear[h][0])
                made[h] = {"adaptive_kf": kf, "arx": arx}
                mixed = combination.mix({"adaptive_kf": kf, "arx": arx}, self.comb.weights(h))
                if math.isfinite(mixed):
                    out[h] = mixed
                if self.corr is not None and math.isfinite(mixed):
                    ahead = {k: float(v[0]) for k, v in correction.ahead_change(x, rows, h).items()}
                    out[h] = self.corr.correct(h, mixed, self._row.get("t_in", math.nan),
                                                self._row | ahead, arx)
        if self.comb is not None and not self._added:
            self.comb.add(made)
            if self.corr is not None:
                self.corr.add()
            self._added = True
        return out

    def reset(self) -> None:
        """After a long gap: the filter, the pending forecasts and the ARX's last pair go; the
        ARX's parameters and the combiner's errors are kept (like the estimator's parameters)."""
        if self.kf is not None:
            self.kf.reset()
        if self.comb is not None:
            self.comb.drop_pending()
        if self.corr is not None:
            self.corr.drop_pending()
        self._arx_prev, self._added = None, True

    def snapshot(self) -> dict:
        prev = self._arx_prev
        return {"kind": self.kind,
                "disturbance": self.kf.snapshot() if self.kf is not None else None,
                "arx": self.arx.snapshot() if self.arx is not None else None,
                "arx_prev": None if prev is None else [prev[0].tolist(), prev[1]],
                "combination": self.comb.snapshot() if self.comb is not None else None,
                "correction": self.corr.snapshot() if self.corr is not None else None,
                "row": self._row, "added": self._added}

    def restore(self, snap: Mapping | None) -> None:
        """Continue from a ``snapshot``; None or another kind's state: start afresh (a
        ``combined`` state goes on as ``corrected``'s parts, the correction starting afresh)."""
        self._start()
        if not snap or snap.get("kind") not in (self.kind, *UPGRADES.get(self.kind, ())):
            return
        if self.kf is not None:
            self.kf.restore(snap["disturbance"])
        if self.arx is not None and snap.get("arx"):
            self.arx.restore(snap["arx"])
        if self.comb is not None:
            self.comb.restore(snap["combination"])
        if self.corr is not None:
            self.corr.restore(snap.get("correction"))
            self._row = dict(snap.get("row") or {})
        prev = snap.get("arx_prev")
        self._arx_prev = None if prev is None else (np.asarray(prev[0], float), float(prev[1]))
        self._added = bool(snap.get("added", True))

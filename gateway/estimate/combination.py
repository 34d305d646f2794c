"""Forecast combination by recent skill: the grey box and the linear baseline, weighted.

Two forecasts of the same T_in[t + h] that err differently are best combined with weights
inversely proportional to their recent mean square errors (Bates & Granger 1969, "The
combination of forecasts", Oper. Res. Q. 20, 451-468, their method (i); Timmermann 2006,
*Handbook of Economic Forecasting* 1, §4: simple inverse-MSE weights usually beat estimated
optimal ones). The weight of forecast i at start t is

    w_i(t) = (1 / MSE_i(t)) / Σ_j (1 / MSE_j(t)),

MSE_i(t) over the forecasts of the last ``WINDOW_S`` whose target is already measured at t (the
starts s ≤ t − h): nothing after t is read. A day-long window holds a day and a night, so the
weights follow which forecast is better lately, not which is better at this hour. Until a
forecast has a matured error, the first one alone is used.
"""

from __future__ import annotations

import base64
import math
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np

WINDOW_S = 86400.0
"""[s] the trailing window of matured forecast errors (one day)."""
PLAUSIBLE_C = (-50.0, 80.0)
"""[°C] the range a greenhouse air temperature forecast can take. A part whose forecast leaves
it (a linear baseline diverging on data that do not excite it) is left out of that start's
combination, and its errors are scored as if it had forecast the range's edge: a tiny weight
times an exploded forecast is still an exploded forecast."""


def implausible(f: np.ndarray | float) -> np.ndarray:
    """True where a forecast is a number outside ``PLAUSIBLE_C`` (±inf included; NaN is not:
    a missing forecast stays missing)."""
    f = np.asarray(f, dtype=float)
    lo, hi = PLAUSIBLE_C
    with np.errstate(invalid="ignore"):
        return ~np.isnan(f) & ~((f >= lo) & (f <= hi))


def scored(f: np.ndarray | float) -> np.ndarray:
    """The forecast as its error is scored: clipped to ``PLAUSIBLE_C`` (NaN stays NaN)."""
    return np.clip(np.asarray(f, dtype=float), *PLAUSIBLE_C)


def mix(forecasts: Mapping[str, float], w: Mapping[str, float]) -> float:
    """Σ w_i f_i over the plausible parts, the weights renormalised over them; NaN when a part is
    missing (NaN) or none is plausible."""
    if any(math.isnan(f) for f in forecasts.values()):
        return math.nan
    ok = {n: f for n, f in forecasts.items() if not implausible(f)}
    total = sum(w[n] for n in ok)
    if not ok or total <= 0.0:
        return math.nan if not ok else float(np.mean(list(ok.values())))
    return sum(w[n] * f for n, f in ok.items()) / total


def trailing_mean(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of the finite values of the last ``window`` samples up to each index (NaN if none)."""
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    s = np.concatenate([[0.0], np.cumsum(np.where(ok, v, 0.0))])
    c = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(1, len(v) + 1)
    lo = np.maximum(idx - window, 0)
    count = c[idx] - c[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, (s[idx] - s[lo]) / count, np.nan)


def weights(forecasts: Mapping[str, np.ndarray], measured: np.ndarray, horizon: int,
            window: int) -> dict[str, np.ndarray]:
    """Inverse-MSE weights per start for ``forecasts`` {name: (T,) forecast of T_in[t + horizon]
    made at t}, ``measured`` (T,) the readings; ``window`` in samples. Causal: the weight at t
    uses the errors of the starts up to t − horizon."""
    n = len(measured)
    m = max(n - horizon, 0)  # starts whose target is in the record (none in one shorter than h)
    target = np.full(n, np.nan)
    target[:m] = np.asarray(measured, dtype=float)[horizon:]
    inv = {}
    for name, f in forecasts.items():
        mse = np.full(n, np.nan)
        mse[horizon:] = trailing_mean((scored(f) - target) ** 2, window)[:m]
        inv[name] = 1.0 / np.maximum(mse, 1e-12)
    total = sum(inv.values())
    names = list(forecasts)
    ready = np.isfinite(total)
    out = {}
    for k, name in enumerate(names):
        first = 1.0 if k == 0 else 0.0
        out[name] = np.where(ready, inv[name] / np.where(ready, total, 1.0), first)
    return out


def combine(forecasts: Mapping[str, np.ndarray], measured: np.ndarray, horizon: int,
            window: int) -> np.ndarray:
    """The combined forecast (T,): Σ_i w_i f_i over the plausible parts, weights renormalised
    over them (NaN where a forecast is NaN or none is plausible; as ``mix``)."""
    w = weights(forecasts, measured, horizon, window)
    f = np.array([np.asarray(v, dtype=float) for v in forecasts.values()])
    ww = np.array([w[name] for name in forecasts])
    ok = ~implausible(f)
    wm = np.where(ok, ww, 0.0)
    total = wm.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mixed = np.where(ok, f, 0.0)
        out = np.where(total > 0.0, (wm * mixed).sum(axis=0) / np.where(total > 0.0, total, 1.0),
                       np.where(ok.any(axis=0), mixed.sum(axis=0) / np.maximum(ok.sum(axis=0), 1),
                                np.nan))
    return np.where(np.isnan(f).any(axis=0), np.nan, out)


class LiveCombiner:
    """The same weights one step at a time, for the live gateway: once per model step
    ``observe`` the reading, take ``weights`` for the forecasts made now, ``add`` them (None
    when none were made). Fed a replay's forecasts it gives ``weights``'s figures."""

    def __init__(self, names: Sequence[str], horizons: Sequence[int], window: int) -> None:
        self.names, self.horizons, self.window = tuple(names), tuple(horizons), window
        self.reset()

    def reset(self) -> None:
        """Forget every pending forecast and error (after a long gap in the data)."""
        self.pending: dict[int, deque] = {h: deque() for h in self.horizons}
        self.errors: dict[int, dict[str, deque]] = {
            h: {n: deque(maxlen=self.window) for n in self.names} for h in self.horizons}

    def drop_pending(self) -> None:
        """Forget the forecasts still waiting for their target (a gap: they will never meet
        it), keep the errors."""
        self.pending = {h: deque() for h in self.horizons}

    def observe(self, reading: float) -> None:
        """The reading now (NaN when missing) scores the forecasts made ``h`` steps ago. Call it
        once per step, before the weights of the forecasts made now and ``add``."""
        for h in self.horizons:
            queue = self.pending[h]
            if len(queue) == h:
                old = queue.popleft()
                for n in self.names:
                    f = math.nan if old is None else old.get(n, math.nan)
                    self.errors[h][n].append((float(scored(f)) - reading) ** 2)

    def add(self, made: Mapping[int, Mapping[str, float]] | None) -> None:
        """The forecasts made now, {horizon: {name: forecast}} (None when none were made)."""
        for h in self.horizons:
            self.pending[h].append(None if made is None or h not in made else dict(made[h]))

    def step(self, reading: float, made: Mapping[int, Mapping[str, float]] | None) -> None:
        """``observe`` then ``add``."""
        self.observe(reading)
        self.add(made)

    def weights(self, horizon: int) -> dict[str, float]:
        """Inverse-MSE weights for a forecast made now at ``horizon`` steps."""
        inv = {}
        for n in self.names:
            e = np.asarray(self.errors[horizon][n], dtype=float)
            e = e[np.isfinite(e)]
            inv[n] = 1.0 / max(float(e.mean()), 1e-12) if e.size else math.nan
        total = sum(inv.values())
        if not math.isfinite(total):
            return {n: 1.0 if k == 0 else 0.0 for k, n in enumerate(self.names)}
        return {n: inv[n] / total for n in self.names}

    def snapshot(self) -> dict:
        """JSON-ready state; the errors (a day of them per horizon and forecast) as base64 of
        their float64 bytes: exact, and half the size of their decimal text."""
        return {"pending": {str(h): list(q) for h, q in self.pending.items()},
                "errors": {str(h): {n: _pack(d) for n, d in e.items()} for h, e in self.errors.items()}}

    def restore(self, snap: Mapping | None) -> None:
        """Continue from a ``snapshot`` (None: start afresh)."""
        self.reset()
        if not snap:
            return
        for h in self.horizons:
            self.pending[h].extend(snap["pending"].get(str(h), []))
            for n in self.names:
                self.errors[h][n].extend(_unpack(snap["errors"].get(str(h), {}).get(n, "")))


def _pack(values: deque) -> str:
    return base64.b64encode(np.asarray(values, dtype="<f8").tobytes()).decode("ascii")


def _unpack(text: str) -> list[float]:
    return np.frombuffer(base64.b64decode(text), dtype="<f8").tolist()

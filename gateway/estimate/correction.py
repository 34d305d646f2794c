"""Horizon-specific error correction of a forecast, learnt online from its own matured errors.

A forecast of T_in[t + h] made at t errs in ways that repeat: a bias the model does not know
(a heater, a storage of the day's sun), an error that persists from one start to the next. A
regression of the error on what is known at the start corrects it, as model output statistics
correct a weather model's output (Glahn & Lowry 1972, "The use of model output statistics (MOS)
in objective weather forecasting", J. Appl. Meteor. 11, 1203-1211), here refitted online so it
follows the season. For each horizon h, with the error e(t) = T_in[t + h] − f(t),

    ê(t) = β(t) · φ(t),     corrected f(t) + ê(t),
    φ(t) = (1, f(t) − T_in[t], e(t − h), I_glob[t] / 1 kW m-2, (T_out − T_in)[t] / 10 K,
            g(t) − f(t), (T_in[t] − 20 °C) / 10 K, (T_in[t] − T̄_in(t)) / 10 K,
            sin ωτ(t), cos ωτ(t), ΔI_glob(t) / 100 W m-2, Δu(t) / 1 m s-1, ΔT_out(t) / 1 K),
    ω = 2π / 24 h, τ the UTC hour,

``T̄_in(t)`` the mean reading of the last day up to t (a controlled house goes back to its
setpoints and its usual temperature: the level and the departure from the day's mean let the
regression learn how far and how fast), ``g`` a second forecast of the same target (the ARX
baseline: the regression re-weights the two, stacking, Wolpert 1992, "Stacked generalization",
Neural Networks 5, 241-259), ``e(t − h)`` the last error already measured at t, and Δ the
change of the forecast's own drivers from its start to the last step it reads
(``ahead_change``: the measured weather for the model-skill forecast, the outlook's for the
live one; the grey box under-responds to a change of its weather, docs/effects.md, "The
correction on the forecast's own weather"). β(t) is the exponentially weighted least squares
estimate with a constant ridge toward "no correction" (Gunnarsson 1996, "Combining tracking and
regularization in recursive least squares identification", Proc. 35th IEEE CDC, 2551-2552):

    β(t) = (R(t) + ρ I)⁻¹ r(t),   R(t) = Σ_s λ^(t−s) φ(s) φ(s)ᵀ,   r(t) = Σ_s λ^(t−s) φ(s) e(s),

over the starts s ≤ t − h only (their target is measured at t): nothing after t is read. The
constant ridge ρ keeps β bounded where forgetting would let an unexcited direction (no sun at
night) wind up, and shrinks the correction toward zero until the errors say otherwise.
λ = exp(−Δt / ``MEMORY_S``): the same memory in time at any model step. A horizon's
correction is applied once it has learnt from a day of matured starts (``WARMUP_S``) and is
bounded (``MAX_CORRECTION_K``). Settings are fixed
here, chosen once on the generality suite's refsim and twonode windows (never on the held-out
generator) and never tuned per greenhouse.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np

MEMORY_S = 4 * 86400.0
"""[s] time constant of the forgetting: the errors of the last four days weigh most."""
RIDGE = 50.0
"""ρ [-], in units of one start's weight: the correction's prior toward zero."""
FEATURES = ("1", "f - t_in", "last error", "i_glob", "t_out - t_in", "arx - f", "t_in level",
            "t_in - day mean", "sin hour", "cos hour", "i_glob ahead", "wind ahead", "t_out ahead")
"""Names of φ, in order: "sin/cos hour" are the hour of the day (UTC) as a daily harmonic, so a
repeated daily error (the sun stored and given back later in the day) is learnt by phase; the
last three are the change of the forecast's own drivers over its horizon (``ahead``)."""
SCALE = np.array([1.0, 1.0, 1.0, 1e-3, 0.1, 1.0, 0.1, 0.1, 1.0, 1.0, 1e-2, 1.0, 1.0])
"""φ in these units (I_glob per kW m-2, temperature differences per 10 K; the changes over the
horizon per 100 W m-2, 1 m s-1 and 1 K, a typical hour's change) so one ridge suits all."""
T_LEVEL_C = 20.0
"""[°C] the reading's level is counted from here (a greenhouse's usual air temperature; the
constant column takes the rest)."""
DAY_MEAN_S = 86400.0
"""[s] the span of the mean reading the departure is counted from."""
WARMUP_S = 86400.0
"""[s] the correction is applied once a horizon has learnt from this long of matured starts (a
day: the daily harmonic is not identified before); until then ``combined`` goes out as it is."""
MAX_CORRECTION_K = 3.0
"""[K] bound on |ê|: a correction larger than that is a fit gone wrong, not a forecast."""


_EXACT_UNIT = 1 << 1074
"""Every finite float64 is a whole multiple of 2^-1074: the day's readings are summed exactly as
integers of that unit (``_exact``)."""


def _exact(value: float) -> int:
    """A finite float as an integer count of 2^-1074 (exact: its denominator is a power of 2)."""
    num, den = value.as_integer_ratio()
    return num * (_EXACT_UNIT // den)


AHEAD = ("i_glob", "wind", "t_out")
"""Drivers whose change over the horizon φ carries (the row keys ``d_i_glob`` …)."""


def ahead_change(x: Mapping[str, np.ndarray], rows: np.ndarray, horizon: int) -> dict[str, np.ndarray]:
    """{``d_<driver>``: (N,)} for a forecast of ``horizon`` steps from each row of ``rows``: the
    driver at the last row the forecast reads (r + horizon − 1 of ``x``: the measured weather,
    or an outlook's block) less its value at the start r, i.e. how the forecast's own weather
    moves over its horizon (model output statistics regress on the model's inputs as well as on
    its output: Glahn & Lowry 1972)."""
    rows = np.asarray(rows, dtype=int)
    last = rows + max(horizon, 1) - 1
    return {f"d_{c}": np.asarray(x[c], dtype=float)[last] - np.asarray(x[c], dtype=float)[rows]
            for c in AHEAD}


def forgetting(dt: float, memory_s: float = MEMORY_S) -> float:
    """λ per model step of ``dt`` [s]."""
    return math.exp(-dt / memory_s)


def features(f: float, t_in: float, last_error: float, row: Mapping[str, float],
             arx: float, day_mean: float = math.nan) -> np.ndarray:
    """φ (scaled, ``FEATURES``) at one start: ``row`` holds ``i_glob``, ``t_out`` and ``hour``
    (UTC, 0-24) at the start and the changes ``d_<driver>`` over the horizon (``ahead_change``),
    ``day_mean`` the mean reading of the last day. A missing last error, ARX forecast, day mean
    or change counts as 0; a missing driver makes φ NaN (no correction)."""
    w = 2.0 * math.pi * row.get("hour", math.nan) / 24.0
    ahead = [row.get(f"d_{c}", math.nan) for c in AHEAD]
    raw = np.array([1.0, f - t_in, last_error if math.isfinite(last_error) else 0.0,
                    row.get("i_glob", math.nan), row.get("t_out", math.nan) - t_in,
                    arx - f if math.isfinite(arx) else 0.0, t_in - T_LEVEL_C,
                    t_in - day_mean if math.isfinite(day_mean) else 0.0, math.sin(w), math.cos(w),
                    *(d if math.isfinite(d) else 0.0 for d in ahead)])
    return raw * SCALE


def hour_of_day(t: np.ndarray) -> np.ndarray:
    """UTC hour of the day (0-24) of datetime64 times."""
    t = np.asarray(t, dtype="datetime64[s]")
    return (t - t.astype("datetime64[D]")).astype(float) / 3600.0


class Corrector:
    """The corrections of every horizon, one model step at a time (live gateway and replay):
    each step ``observe`` the reading, then ``correct`` the forecasts made now, then ``add``."""

    def __init__(self, horizons: Sequence[int], dt: float, memory_s: float = MEMORY_S,
                 ridge: float = RIDGE, warmup_s: float = WARMUP_S) -> None:
        self.horizons, self.lam, self.ridge = tuple(horizons), forgetting(dt, memory_s), ridge
        self.warmup = int(math.ceil(warmup_s / dt))  # learnt starts before the first correction
        self.day = max(int(round(DAY_MEAN_S / dt)), 1)  # readings in the day mean
        self._ridge = ridge * np.eye(len(FEATURES))  # ρ I of ``beta``, the same bits each step
        self.reset()

    def reset(self) -> None:
        k = len(FEATURES)
        self.r_mat = {h: np.zeros((k, k)) for h in self.horizons}
        self.r_vec = {h: np.zeros(k) for h in self.horizons}
        self.last = {h: math.nan for h in self.horizons}
        self.learnt = dict.fromkeys(self.horizons, 0)
        self.pending: dict[int, deque] = {h: deque() for h in self.horizons}
        self._made: dict[int, list[float]] = {}
        self.readings: deque = deque(maxlen=self.day)  # the last day's readings (NaN kept)
        self._finite = 0  # how many of them are finite
        self._sum = 0  # their exact sum, in units of 2^-1074 (``_exact``)
        self.day_mean = math.nan

    def drop_pending(self) -> None:
        """A gap: the forecasts waiting for a target will never meet it; β is kept."""
        self.pending = {h: deque() for h in self.horizons}
        self.last = {h: math.nan for h in self.horizons}
        self._made = {}

    def observe_reading(self, reading: float | None) -> None:
        """The reading joins the last day's mean (``observe`` does this itself)."""
        value = math.nan if reading is None else float(reading)
        if len(self.readings) == self.day and math.isfinite(self.readings[0]):
            self._finite -= 1  # the oldest reading leaves the day
            self._sum -= _exact(self.readings[0])
        self.readings.append(value)
        if math.isfinite(value):
            self._finite += 1
            self._sum += _exact(value)
        # The sum is exact and an int / int division is correctly rounded: the same float as
        # math.fsum of the finite readings (also correctly rounded), without a pass over the
        # day's readings (a day of 1-minute readings, every step).
        got = self._finite
        self.day_mean = self._sum / _EXACT_UNIT / got if got else math.nan

    def observe(self, reading: float) -> None:
        """The reading now matures the forecasts made h steps ago: forget, then learn each;
        it joins the day's mean."""
        self.observe_reading(reading)
        for h in self.horizons:
            queue = self.pending[h]
            if len(queue) < h:
                continue
            old = queue.popleft()
            if old is None:
                self.last[h] = math.nan
                continue
            f = old[-1]
            e = reading - f
            self.last[h] = e
            if not (math.isfinite(e) and all(map(math.isfinite, old))):
                continue
            phi = np.array(old[:-1], dtype=float)
            # in place: the same operations as λ R + φ φᵀ and λ r + φ e, no new arrays
            r_mat, r_vec = self.r_mat[h], self.r_vec[h]
            r_mat *= self.lam
            r_mat += np.multiply.outer(phi, phi)
            r_vec *= self.lam
            r_vec += phi * e
            self.learnt[h] += 1

    def beta(self, h: int) -> np.ndarray:
        return np.linalg.solve(self.r_mat[h] + self._ridge, self.r_vec[h])

    def correct(self, h: int, f: float, t_in: float, row: Mapping[str, float],
                arx: float = math.nan) -> float:
        """The corrected forecast of horizon ``h`` made now from the reading ``t_in``, the
        drivers ``row`` (``features``) and the ARX's forecast of the same target; ``f``
        unchanged where φ cannot be formed. Remembered for ``add``."""
        phi = features(f, t_in, self.last[h], row, arx, self.day_mean)
        values = phi.tolist()
        if not (math.isfinite(f) and all(map(math.isfinite, values))):
            return f
        self._made[h] = [*values, f]
        if self.learnt[h] < self.warmup:
            return f
        e_hat = float(self.beta(h) @ phi)  # bounded as np.clip would (NaN stays NaN)
        return f + min(max(e_hat, -MAX_CORRECTION_K), MAX_CORRECTION_K)

    def add(self) -> None:
        """Close the step: the forecasts ``correct`` saw now wait h steps for their target."""
        for h in self.horizons:
            self.pending[h].append(self._made.get(h))
        self._made = {}

    def snapshot(self) -> dict:
        return {"r_mat": {str(h): m.tolist() for h, m in self.r_mat.items()},
                "r_vec": {str(h): v.tolist() for h, v in self.r_vec.items()},
                "last": {str(h): v for h, v in self.last.items()},
                "learnt": {str(h): v for h, v in self.learnt.items()},
                "pending": {str(h): list(q) for h, q in self.pending.items()},
                "readings": list(self.readings)}

    def restore(self, snap: Mapping | None) -> None:
        """Continue from a ``snapshot`` (None, or one made with other features: start
        afresh)."""
        self.reset()
        if not snap:
            return
        k = len(FEATURES)
        if any(np.shape(m) != (k, k) for m in snap.get("r_mat", {}).values()):
            return  # an older φ: its sums and pending starts do not fit this one
        for v in snap.get("readings", []):
            self.observe_reading(v)
        for h in self.horizons:
            key = str(h)
            if key in snap.get("r_mat", {}):
                self.r_mat[h] = np.array(snap["r_mat"][key], dtype=float)  # a copy: updated in place
                self.r_vec[h] = np.array(snap["r_vec"][key], dtype=float)
            last = snap.get("last", {}).get(key)
            self.last[h] = math.nan if last is None else float(last)
            self.learnt[h] = int(snap.get("learnt", {}).get(key, 0))
            self.pending[h].extend(snap.get("pending", {}).get(key, []))


def correct_series(forecasts: Mapping[int, np.ndarray], measured: np.ndarray,
                   x: Mapping[str, np.ndarray], time: np.ndarray, dt: float,
                   arx: Mapping[int, np.ndarray] | None = None, memory_s: float = MEMORY_S,
                   ridge: float = RIDGE, warmup_s: float = WARMUP_S,
                   ahead: Mapping[int, Mapping[str, np.ndarray]] | None = None,
                   ) -> dict[int, np.ndarray]:
    """``forecasts`` {h: (T,) forecast of T_in[t + h] made at t}, on the series' grid (NaN where
    none was made; ``arx`` the same for the ARX, stacked; ``ahead`` {h: ``ahead_change`` of each
    start, (T,) per key}), corrected by ``Corrector`` run step by step: the figures the live
    gateway gives."""
    n = len(measured)
    corr = Corrector(list(forecasts), dt, memory_s, ridge, warmup_s)
    out = {h: np.full(n, np.nan) for h in forecasts}
    nan = np.full(n, np.nan)
    # Python floats of every column once (.tolist() gives the values float() of each gives)
    g = {h: np.asarray((arx or {}).get(h, nan), dtype=float).tolist() for h in forecasts}
    f_of = {h: np.asarray(f, dtype=float).tolist() for h, f in forecasts.items()}
    cols = {"i_glob": x["i_glob"], "t_out": x["t_out"], "hour": hour_of_day(time)}
    col_of = {k: np.asarray(v).tolist() for k, v in cols.items()}
    ahead_of = {h: {k: np.asarray(v).tolist() for k, v in (ahead or {}).get(h, {}).items()}
                for h in forecasts}
    readings = np.asarray(measured, dtype=float).tolist()
    for t in range(n):
        reading = readings[t]
        corr.observe(reading)
        row = {k: v[t] for k, v in col_of.items()}
        for h, f in f_of.items():
            if math.isfinite(f[t]):
                row_h = row | {k: v[t] for k, v in ahead_of[h].items()}
                out[h][t] = corr.correct(h, f[t], reading, row_h, g[h][t])
        corr.add()
    return out

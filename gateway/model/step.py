"""The exponential step every model evaluation uses (docs/model-notes.md §4, issue 10).

The air balance is ``dT/dt = r(T, t)`` with the rate ``r = F / C`` [K s-1], F the net flux
[W m-2] and C the heat capacity [J m-2 K-1]. Over one step of length Δ from t_k to t_k+1:

- **zero-order hold** (the thesis-era step): drivers and coefficients frozen at t_k,

      T+ = T + Δ r0 φ1(z),                       z = λ0 Δ

- **first-order hold with re-linearisation** (the default since issue 10): the drivers move
  linearly from the sample at t_k to the one at t_k+1, and the exponent is the true slope
  λ = -∂r/∂T (h_i ∝ |T_in − T_out|^0.33 makes it steeper than the coefficient s alone). This is
  the exponential Rosenbrock–Euler step of the system with time as a second state
  (Hochbruck, Ostermann & Schweitzer 2009, SIAM J. Numer. Anal. 47):

      T+ = T + Δ [r0 φ1(z) + (r1 − r0) φ2(z)],   z = (λ0 + λ1)/2 Δ

  with r0 = r(T, t_k), and r1 the rate at t_k+1 evaluated at the midpoint state
  T_m = T + Δ/2 r0 φ1(λ0 Δ) and carried back to T: r1 = r(T_m, t_k+1) + λ1 (T_m − T). It is
  second order; both evaluations are of the same cost as the old one.

``φ1(z) = (1 − e^-z)/z`` and ``φ2(z) = (z − 1 + e^-z)/z²`` are finite at z → 0 (1 and 1/2)
and bounded for any z ≥ 0, so the step stays unconditionally stable for the stiff corners of
table 13. Where the sample at t_k+1 is missing (a gap, or the end of the data: the live
estimator predicting the next minute) the step falls back to the zero-order hold.

Why: identified from fine RK4 data of the same prototype equations with drivers that vary
within the minute, the zero-order hold biases the four prototype parameters by ~6 % at 1 min and
~40 % at 5 min (a half-step lag of every driver); docs/model.md has the table.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import overload

import numpy as np

from gateway.model.terms import Index, const, row_columns

HOLDS = ("first_order", "zero_order")

BLOCK_ELEMENTS = 4096
"""Population × time elements per block of the one-step evaluations (``Model.one_step``, the
calibration cost's fast path): each temporary (32 kB) stays below glibc's mmap and trim
thresholds (128 kB), so the ~40 temporaries of a block reuse heap memory instead of faulting
fresh pages in (blocks of 16384 ran 1.6-2x slower for that alone, more than the loop over
smaller blocks costs; measured with tests/bench/step.py's calibration cost)."""

_HALF, _ONE, _Z_MIN = const(0.5), const(1.0), const(1e-6)  # 0-d operands (terms.const)
_Z_TINY = const(1e-12)  # phi1's floor

Rates = Callable[[np.ndarray, Index], tuple[np.ndarray, np.ndarray]]
"""``rates(state, t) -> (r, λ)``: rate dT/dt [K s-1] at ``state`` and time index ``t``, and the
slope λ = -∂r/∂T [s-1] the exponential relaxes with."""


@dataclass(frozen=True)
class Integration:
    """How a model integrates one step.

    ``hold``: ``first_order`` (drivers linear between samples) or ``zero_order`` (frozen at the
    step's start, the step before issue 10); ``relinearise``: the exponent is the true slope
    -∂r/∂T and the end of the step is evaluated at the midpoint state (False: the coefficient
    s frozen at the start state, as before issue 10).
    """

    hold: str = "first_order"
    relinearise: bool = True

    def __post_init__(self) -> None:
        if self.hold not in HOLDS:
            raise ValueError(f"hold must be one of {HOLDS}, got {self.hold!r}")


FROZEN = Integration("zero_order", relinearise=False)
"""The step before issue 10: everything frozen at the start of the step."""


def phi(z: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(φ1(z), φ2(z)) for z ≥ 0. φ2 = (1 - φ1)/z: below z = 1e-6 (a step that barely relaxes)
    z is taken as 1e-6, which moves φ1 by < 5e-7 and keeps φ2 = 1/2 - z/6 to 4e-10."""
    z = np.maximum(z, _Z_MIN)
    nz = -z
    p1 = np.expm1(nz) / nz  # (1 - e^-z)/z: the same bits as -expm1(-z)/z, one operation less
    return p1, (_ONE - p1) / z


def phi1(z: np.ndarray | float) -> np.ndarray:
    """φ1(z) = (1 - e^-z)/z for z ≥ 0, 1 at z → 0."""
    nz = -np.maximum(z, _Z_TINY)
    return np.expm1(nz) / nz  # the same bits as -expm1(-z)/z, one operation less (``phi``)


def advance(state: np.ndarray, r0: np.ndarray, lam: np.ndarray | float, dt: float | np.ndarray,
            r1: np.ndarray | None = None) -> np.ndarray:
    """T + Δ [r0 φ1(z) + (r1 − r0) φ2(z)], z = λΔ: exact for a rate linear in T with slope -λ
    and a forcing linear in time from r0 to r1 (``r1`` None: constant forcing, φ1 only)."""
    if r1 is None:
        return state + r0 * dt * phi1(lam * dt)
    p1, p2 = phi(lam * dt)
    return state + dt * (r0 * (p1 - p2) + r1 * p2)


def midpoint(state: np.ndarray, r0: np.ndarray, lam0: np.ndarray, dt: float,
             half: np.ndarray | None = None) -> np.ndarray:
    """Halfway to where the frozen step would end (the predictor the end of the step is
    evaluated at), with φ1(z) ≈ 1/(1 + z/2): exact to z²/12, bounded, and no exponential.
    ``half``: Δ/2 as a 0-d array when the caller holds it (``terms.const``), else made here."""
    if half is None:
        half = const(0.5 * dt)
    return state + half * r0 / (_ONE + half * lam0)


@overload
def next_index(t: int, n: int) -> int: ...
@overload
def next_index(t: Index, n: int) -> Index: ...
def next_index(t: Index, n: int) -> Index:
    """The time index one step on, clipped to the last sample ``n - 1`` (there the step holds)."""
    if isinstance(t, slice):
        a, b = t.start or 0, n if t.stop is None else t.stop
        if b < n:
            return slice(a + 1, b + 1)
        return np.minimum(np.arange(a, b) + 1, n - 1)
    if isinstance(t, np.ndarray):
        return np.minimum(t + 1, n - 1)
    return min(int(t) + 1, n - 1)


def end_rates(rates: Rates, state: np.ndarray, r0: np.ndarray, lam0: np.ndarray, t1: Index,
              dt: float, relinearise: bool, fixed: tuple[np.ndarray, np.ndarray] | None = None,
              check: bool = True, half: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(r1, λ1) at t_k+1 referred to the start state (see the module docstring); where the
    sample at t_k+1 is missing, the start's (r0, λ0): the zero-order hold. ``fixed``: a part of
    (r1, λ1) already known at the start state (terms that do not read the state), added as is;
    ``rates`` then gives the rest. ``check=False``: the caller knows nothing is missing.
    ``half``: Δ/2 as a 0-d array (``midpoint``)."""
    if relinearise:
        tm = midpoint(state, r0, lam0, dt, half)
        r1, lam1 = rates(tm, t1)
        r1 = r1 + lam1 * (tm - state)
    else:
        r1, lam1 = rates(state, t1)
    if fixed is not None:
        r1, lam1 = r1 + fixed[0], lam1 + fixed[1]
    if not check:
        return r1, lam1
    both = r1 + lam1
    if not math.isfinite(np.add.reduce(both, axis=None)):  # one reduction, no temporary mask
        bad = ~np.isfinite(both)
        r1, lam1 = np.where(bad, r0, r1), np.where(bad, lam0, lam1)
    return r1, lam1


Sums = Callable[[np.ndarray, Index], tuple]
"""``sums(state, t) -> (g, s, k)``: a group of terms' summed coefficients (Q = g - s T) and
slope k = -∂Q/∂T at ``state`` and time index ``t`` [W m-2, W m-2 K-1, W m-2 K-1]."""
RowSums = Callable[[np.ndarray, int], tuple]
"""``Sums`` for one row ``t`` at a time (the terms' ``FluxTerm.bind``)."""


def _same(a: Index, b: Index) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape
                and bool(np.array_equal(a, b)))
    return a == b


def _rate(g: np.ndarray, s: np.ndarray, k: np.ndarray, state: np.ndarray,
          c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r = (g − s T)/C [K s-1], λ = k/C [s-1]) of summed coefficients (``Sums``) at ``state``."""
    return (g - s * state) / c, k / c


class Stepper:
    """The one exponential step of every model evaluation, bound to one set of drivers (of
    length ``n``) and parameters: ``stepper(state, t)`` steps from time index ``t``.

    ``fixed`` sums the terms whose coefficients do not read the state, ``moving`` the others.
    When ``t`` is one step (free runs, the online estimator's virtual model: the per-call cost
    of small arrays dominates at small populations) the work that does not read the state is
    done once for a block of ``BLOCK`` rows: the fixed terms' sums (and their slope over C), and,
    with ``bind`` (``bind(rows)``: the moving terms' sums with their state-free parts computed
    for the rows, ``FluxTerm.bind``), the moving terms' parameter-and-driver parts. Consecutive
    calls with a slice or an array reuse the fixed sums at t + 1 as the next step's start, so
    the first-order hold costs the fixed terms one evaluation per step, not two. The numbers are
    the same either way (element-wise operations).
    """

    BLOCK = 64
    """Rows of the state-free work done at once when stepping one time index at a time."""

    def __init__(self, fixed: Sums, moving: Sums, c: float, dt: float, n: int,
                 integration: Integration = Integration(),
                 bind: Callable[[slice], RowSums] | None = None) -> None:
        self.fixed, self.moving, self.bind = fixed, moving, bind
        self.c, self.dt, self.n, self.integration = c, dt, n, integration
        # C and Δ as 0-d arrays for the per-step arithmetic: the same float64 operations, but
        # numpy 2 converts a Python float operand on every call (~0.3 µs at small P).
        self._c, self._dt = np.array(c, dtype=float), np.array(dt, dtype=float)
        self._half = const(0.5 * dt)  # Δ/2 of ``midpoint``, built once
        self._rows_fast = integration.hold == "first_order"
        self._key: Index | None = None
        self._cached: tuple = ()
        self._rows = (0, 0)  # rows [a, b) of the block held
        self._table: list[tuple] = []  # fixed (g, s, k, k / C) per row of the block
        self._bound: RowSums = moving  # the moving sums bound to the block's rows

    def reset(self) -> None:
        """Forget the block of rows held: the parameter columns it was computed from have been
        rewritten in place (the online estimator's cost builds one stepper per search and calls
        this for each population it evaluates). The next step is then what a new stepper's
        would be."""
        self._rows, self._key, self._cached = (0, 0), None, ()

    def _block(self, state: np.ndarray, t: int) -> int:
        """Row ``t``'s position in the block held, computing the block first when ``t`` is not in
        it."""
        a, b = self._rows
        if not a <= t < b:
            a, b = t, min(t + self.BLOCK, self.n)
            self._rows = (a, b)
            g, s, k = self.fixed(state, slice(a, b))
            sums = (g, s, k, np.asarray(k) / self._c)
            self._table = list(zip(*(row_columns(v, b - a) for v in sums), strict=True))
            if self.bind is not None:
                self._bound = self.bind(slice(a, b))
        return t - a

    def _fixed_at(self, state: np.ndarray, t: Index) -> tuple:
        if isinstance(t, (int, np.integer)):
            j = self._block(state, int(t))  # before reading self._table: it may replace it
            return self._table[j][:3]
        if self._key is not None and _same(self._key, t):
            return self._cached
        return self.fixed(state, t)

    def _moving_at(self, state: np.ndarray, t: Index) -> tuple:
        if isinstance(t, (int, np.integer)):
            self._block(state, int(t))
            return self._bound(state, t)
        return self.moving(state, t)

    def rates(self, state: np.ndarray, t: Index) -> tuple[np.ndarray, np.ndarray]:
        """(r [K s-1], λ [s-1]) of all terms at ``state`` and ``t``."""
        gi, si, ki = self._fixed_at(state, t)
        gd, sd, kd = self._moving_at(state, t)
        return _rate(gi + gd, si + sd, ki + kd, state, self._c)

    def _moving_rates(self, state: np.ndarray, t: Index) -> tuple[np.ndarray, np.ndarray]:
        g, s, k = self._moving_at(state, t)
        return _rate(g, s, k, state, self._c)

    def _bound_rates(self, state: np.ndarray, t: Index) -> tuple[np.ndarray, np.ndarray]:
        """``_moving_rates`` at a row ``t`` (an int) of the block held (the caller has just
        placed it)."""
        g, s, k = self._bound(state, t)  # type: ignore[arg-type]  # one row: end_rates passes t1
        return _rate(g, s, k, state, self._c)

    def _step_row(self, state: np.ndarray, t: int) -> np.ndarray:
        """``__call__`` for one row ``t`` with the default integration: the same operations on
        the same operands, the block's sums read once per step rather than through
        ``rates``/``_fixed_at``/``_moving_at`` (a step of a 20-bat population is ~100 small
        numpy operations; the Python around them is a small share: docs/online-estimator.md,
        "Replay speed", where folding it back into ``__call__`` measured 1.17x on
        ``prototype+vent_control``)."""
        c = self._c
        j = self._block(state, t)  # before reading self._table: it may replace it
        gi, si, ki, _ = self._table[j]
        gd, sd, kd = self._bound(state, t)
        r0, lam0 = _rate(gi + gd, si + sd, ki + kd, state, c)  # ``rates``
        t1 = t + 1 if t + 1 < self.n else self.n - 1  # ``next_index``
        j = self._block(state, t1)
        g1, s1, _, k1_c = self._table[j]
        fixed = ((g1 - s1 * state) / c, k1_c)  # ``_rate`` with the block's k / C
        r1, lam1 = end_rates(self._bound_rates, state, r0, lam0, t1, self.dt,
                             self.integration.relinearise, fixed=fixed, half=self._half)
        return advance(state, r0, _HALF * (lam0 + lam1), self._dt, r1)

    def __call__(self, state: np.ndarray, t: Index) -> np.ndarray:
        if self._rows_fast and isinstance(t, (int, np.integer)):
            return self._step_row(state, int(t))
        c, dt = self._c, self._dt
        r0, lam0 = self.rates(state, t)
        if self.integration.hold == "zero_order":
            return advance(state, r0, lam0, dt)
        t1 = next_index(t, self.n)  # a slice or an array here: one row went to _step_row
        g1, s1, k1 = self.fixed(state, t1)
        self._key, self._cached = t1, (g1, s1, k1)
        r1, lam1 = end_rates(self._moving_rates, state, r0, lam0, t1, self.dt,
                             self.integration.relinearise, fixed=_rate(g1, s1, k1, state, c))
        return advance(state, r0, _HALF * (lam0 + lam1), dt, r1)

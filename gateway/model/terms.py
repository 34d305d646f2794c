"""The vocabulary of a climate model: parameters, activity conditions and heat-flux terms.

A model is a list of flux terms (docs/architecture.md). Each term contributes to the air heat
balance ``C dT_in/dt = sum_k Q_k`` a flux that is affine in the state once the step's
coefficients are frozen:

    Q_k = g_k - s_k * T_in          g_k [W m-2], s_k [W m-2 K-1]

which is what the exact exponential step (docs/model-notes.md §4) needs. ``coefficients`` evaluates
(g_k, s_k) for a whole population of parameter sets at once: parameter columns arrive with
shape (P, 1) and broadcast against the time axis, so the calibrators, the online estimator and
the diagnosis never loop over candidates.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial

import numpy as np

Index = int | slice | np.ndarray
"""A time index into the drivers: one step, a slice, or an array of steps (one per row)."""
Linearised = Callable[[np.ndarray, int], tuple]
"""``fn(t_in, t) -> (g, s, k)``: a term's ``linearised`` with its parameters and drivers bound,
for one time index at a time (``FluxTerm.bind``)."""


def const(value: float) -> np.ndarray:
    """A constant operand of the per-step arithmetic as a 0-d float64 array: the same float64
    operations as with the Python float, but numpy 2 converts a Python float (or numpy scalar)
    operand at every call, ~40 % of an operation on the small (P, 1) arrays of a model step."""
    return np.array(value, dtype=float)


def row_values(column: np.ndarray, rows: slice) -> list[np.ndarray]:
    """A driver column's values at ``rows`` as 0-d arrays (operands of a bound term: ``const``)."""
    return [column[t, ...] for t in range(rows.start, rows.stop)]


def row_columns(v: np.ndarray | float, rows: int) -> list:
    """A block of values (P or 1, rows) as one contiguous (P or 1, 1) column per row; a value
    that does not vary in time (a scalar, (P, 1)) as it is for every row. (A column view of
    the block is strided, and an operation on a strided (P, 1) array costs about twice as much
    at small P.) The numbers are the block's."""
    v = np.asarray(v)
    if v.ndim == 1:
        v = v[None, :]
    if v.ndim == 0 or v.shape[1] == 1:
        return [v] * rows
    return list(np.ascontiguousarray(v.T)[:, :, None])


@dataclass(frozen=True)
class Condition:
    """When a physical process is active, so that its parameters may be re-estimated."""

    name: str
    description: str
    test: Callable[[Mapping[str, np.ndarray]], np.ndarray]

    def __call__(self, x: Mapping[str, np.ndarray]) -> np.ndarray:
        return np.asarray(self.test(x), dtype=bool)


SUN_THRESHOLD = 5.0
"""Outside radiation above which solar processes count as active [W m-2] (§IV.2.1.2)."""
LAI_THRESHOLD = 0.1
"""Leaf area index above which transpiration counts as active [m2 m-2] (§IV.2.1.2)."""

# Named functions, not lambdas: a model (and a replay result holding it) must pickle, for the
# process pools of the studies and the suite.
def _always(x: Mapping[str, np.ndarray]) -> np.ndarray:
    return np.ones_like(x["t_out"], dtype=bool)


def _sunlit(x: Mapping[str, np.ndarray]) -> np.ndarray:
    return x["i_glob"] > SUN_THRESHOLD


def _vents_open(x: Mapping[str, np.ndarray]) -> np.ndarray:
    return (x["a_roof"] + x["a_side"]) > 0.0


def _crop(x: Mapping[str, np.ndarray]) -> np.ndarray:
    return x["lai"] > LAI_THRESHOLD


def _crop_day(x: Mapping[str, np.ndarray]) -> np.ndarray:
    return _crop(x) & _sunlit(x)


def _crop_night(x: Mapping[str, np.ndarray]) -> np.ndarray:
    return _crop(x) & ~_sunlit(x)


ALWAYS = Condition("always", "always active", _always)
SUNLIT = Condition("sunlit", f"outside radiation > {SUN_THRESHOLD:g} W m-2", _sunlit)
VENTS_OPEN = Condition("vents_open", "a roof or side vent is open", _vents_open)
CROP_DAY = Condition(
    "crop_day", f"LAI > {LAI_THRESHOLD:g} and radiation > {SUN_THRESHOLD:g} W m-2", _crop_day
)
CROP_NIGHT = Condition(
    "crop_night", f"LAI > {LAI_THRESHOLD:g} and radiation <= {SUN_THRESHOLD:g} W m-2", _crop_night
)
CROP = Condition("crop", f"LAI > {LAI_THRESHOLD:g}", _crop)


@dataclass(frozen=True)
class Parameter:
    """One parameter of a flux term.

    ``lower``/``upper`` are the hard bounds (thesis table 13 or §III.4.2.1.2.A); ``variation``
    is the online variation ratio R_j of table 12 (the search box is re-centred each step at
    C_j (1 ± R_j)); None means the whole hard box is searched every time (as the thesis does
    for c_tsw).
    """

    name: str
    unit: str
    lower: float
    upper: float
    default: float
    variation: float | None
    active: Condition
    description: str

    def __post_init__(self) -> None:
        if not self.lower <= self.default <= self.upper:
            raise ValueError(f"{self.name}: default {self.default} outside [{self.lower}, {self.upper}]")


Params = Mapping[str, np.ndarray]
Drivers = Mapping[str, np.ndarray]


class FluxTerm:
    """A heat flux into the inside air [W m-2] (negative for losses).

    Subclasses set ``name`` (``q_<name>``), ``equation`` (thesis number), ``parameters``,
    ``requires`` (driver columns it reads) and implement ``coefficients``.
    """

    name: str = "q"
    equation: str = ""
    description: str = ""
    parameters: tuple[Parameter, ...] = ()
    requires: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()
    """Kit columns the term reads when the data has them; without them ``prepare_drivers``
    gives a stand-in (gateway/model/drivers.py) and the tools say so (gateway/cli/notes.py)."""
    uses: tuple[str, ...] = ()  # parameters owned by another part of the model (e.g. c_tsw)
    linear_in_parameters: bool = False
    """True when (g, s) = sum_j theta_j (g_j, s_j) over the term's own parameters for a given
    state (the ``uses`` parameters held fixed): a one-step cost can then precompute the
    (g_j, s_j) once and evaluate a whole population with one matrix product."""
    state_dependent: bool = True
    """False when (g, s) do not depend on ``t_in``: the flux is then affine in the state and its
    slope is s (``linearised`` need not be overridden)."""
    derives: tuple[str, ...] = ()
    """Keys of the driver-only columns ``derive`` computes (each starting with ``_``)."""

    def derive(self, x: Drivers) -> dict[str, np.ndarray]:
        """Columns the term reads that depend on the drivers only (e.g. ventilation's buoyancy
        coefficient from the vent areas), over the whole series: ``Model.prepare`` adds them to
        the drivers once, so a step for a population of candidates only indexes them. A term
        must give the same values when they are absent (``derived``)."""
        return {}

    def derived(self, x: Drivers, key: str, t: Index) -> np.ndarray | None:
        """The column ``key`` of ``derive`` at ``t`` when ``Model.prepare`` added it, else None
        (the term then computes it from ``x`` at ``t``)."""
        col = x.get(key)
        return None if col is None else col[t]

    def coefficients(
        self, p: Params, x: Drivers, t_in: np.ndarray, t: Index
    ) -> tuple[np.ndarray, np.ndarray]:
        """(g [W m-2], s [W m-2 K-1]) with Q = g - s T_in, for state ``t_in`` at time ``t``."""
        raise NotImplementedError

    def linearised(
        self, p: Params, x: Drivers, t_in: np.ndarray, t: Index
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(g, s, k): the coefficients plus the slope k = -∂Q/∂T_in [W m-2 K-1] at ``t_in``,
        the rate the exponential step relaxes with (gateway/model/step.py). k = s unless the
        coefficients depend on the state; such terms override this with the exact slope."""
        g, s = self.coefficients(p, x, t_in, t)
        return g, s, s

    def bind(self, p: Params, x: Drivers, rows: slice) -> Linearised:
        """``linearised`` with ``p`` and ``x`` bound, called with one time index t inside
        ``rows`` at a time (the free runs of ``step.Stepper``, which evaluate a state-dependent
        term twice per step). A term whose (g, s, k) hold parts that read the parameters and
        drivers but not the state overrides this to compute those once for the rows, as a block
        (element-wise: the same numbers as ``linearised``)."""
        return partial(self.linearised, p, x)

    def flux(self, p: Params, x: Drivers, t_in: np.ndarray, t: Index) -> np.ndarray:
        """The flux Q [W m-2] at state ``t_in`` (°C)."""
        g, s = self.coefficients(p, x, t_in, t)
        return g - s * t_in

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} ({self.equation})>"


class SensorTerm:
    """An observation error of the inside temperature sensor (issue 4, diagnosis).

    It changes what is *measured*, not the heat balance: ``T_meas = T_true + offset``. The model
    integrates the true state and adds the offset to what it reports (and removes it from a
    measured state it restarts from). Subclasses set ``name``, ``description``, ``parameters``,
    ``requires`` and implement ``offset`` [K] for parameter columns (P, 1) at time ``t``.
    """

    name: str = "e"
    description: str = ""
    parameters: tuple[Parameter, ...] = ()
    requires: tuple[str, ...] = ()

    def offset(self, p: Params, x: Drivers, t: Index) -> np.ndarray:
        """Measured minus true inside temperature [K]."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}>"

"""A climate model as a list of flux terms, integrated with the exponential step.

``C dT_in/dt = sum_k (g_k - s_k T_in)``; with the coefficients frozen over one step of length
dt the solution is exact (docs/model-notes.md §4):

    T+ = T + (G - S T) dt/C * phi(S dt / C),   phi(z) = (1 - exp(-z)) / z

which equals ``T_eq + (T - T_eq) exp(-S dt/C)`` with ``T_eq = G/S`` and stays finite as S → 0.
It is unconditionally stable, so the stiff coefficients of table 13 (C_cnd_cnv up to
300 W m-2 K-1) are safe at a 60 s step where explicit Euler diverges. Since issue 10 the
drivers move linearly between samples and the exponent is the flux's true slope
(gateway/model/step.py, ``Model.integration``; docs/model.md): freezing them biased the
identified parameters by ~6 % at 1 min.

Both evaluation modes take parameters of shape (P, k) and return predictions of shape (P, T)
with no Python loop over P.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Self, TypeVar

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import step as stepping
from gateway.model.radiation import RadiationSubmodel
from gateway.model.step import Integration
from gateway.model.terms import FluxTerm, Index, Parameter, SensorTerm

__all__ = ["Model", "OnlineGroup", "RadiationSubmodel", "check_columns"]

IndexT = TypeVar("IndexT")
"""The time index a sum of terms takes: any ``Index`` (``FluxTerm.linearised``), or one row
``int`` (``FluxTerm.bind``, whose bound values are per row)."""


@dataclass(frozen=True)
class OnlineGroup:
    """Parameters re-estimated together by the online estimator (§IV.2.2.2).

    ``output`` is the measured variable the group is fitted on (``t_in`` or ``i_in``),
    ``parameters`` the names (empty: every parameter not claimed by another group), ``window``
    the number n of past samples re-simulated, ``every`` the period in model steps.
    """

    output: str
    parameters: tuple[str, ...]
    window: int
    every: int


@dataclass(frozen=True)
class Model:
    """A named set of flux terms plus the heat capacity and optional radiation sub-model."""

    name: str
    terms: tuple[FluxTerm, ...]
    capacity: Callable[[Greenhouse], float]
    """Heat capacity of the air node per floor area C [J m-2 K-1] (III.24), or ρV/S_f for the
    prototype whose lumped parameters already absorb 1/C_a (III.14)."""
    radiation: RadiationSubmodel | None = None
    description: str = ""
    capacity_equation: str = ""
    extra: tuple[Parameter, ...] = field(default=())
    online: tuple[OnlineGroup, ...] = (OnlineGroup("t_in", (), 3, 1),)
    """Online estimation groups: air temperature every step with n = 3 (thesis default)."""
    sensors: tuple[SensorTerm, ...] = ()
    """Observation terms: measured T_in = true T_in + sum of offsets (default none: the sensor
    reads the true state). Added by the diagnosis (gateway/diagnose) for sensor errors."""
    integration: Integration = Integration()
    """How one step is integrated (gateway/model/step.py): first-order hold of the drivers and
    the re-linearised slope by default; ``step.FROZEN`` is the step before issue 10."""

    # -- the parameter vector -------------------------------------------------------------
    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """All parameters in vector order: terms' first, then the radiation sub-model's."""
        seen: dict[str, Parameter] = {}
        for term in self.terms:
            for p in term.parameters:
                seen.setdefault(p.name, p)
        for p in self.extra:
            seen.setdefault(p.name, p)
        for sensor in self.sensors:
            for p in sensor.parameters:
                seen.setdefault(p.name, p)
        if self.radiation is not None:
            seen.setdefault(self.radiation.parameter.name, self.radiation.parameter)
        return tuple(seen.values())

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def requires(self) -> list[str]:
        cols = ["t_in"]
        parts: tuple[FluxTerm | SensorTerm, ...] = (*self.terms, *self.sensors)
        for term in parts:
            cols += [c for c in term.requires if c not in cols]
        return cols

    def index(self, name: str) -> int:
        return self.names.index(name)

    def bounds(self, gh: Greenhouse | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Hard bounds (lower, upper) of shape (k,), with the greenhouse's overrides."""
        lo = np.array([p.lower for p in self.parameters])
        hi = np.array([p.upper for p in self.parameters])
        if gh is not None:
            for j, p in enumerate(self.parameters):
                b = gh.parameters.get(p.name, {}).get("bounds")
                if b is not None:
                    lo[j], hi[j] = b
        return lo, hi

    def defaults(self, gh: Greenhouse | None = None) -> np.ndarray:
        """Default parameter vector (k,): published values, the greenhouse's overrides, c_tsw
        from the greenhouse's cover transmission."""
        theta = np.array([p.default for p in self.parameters])
        if gh is not None:
            for j, p in enumerate(self.parameters):
                if p.name == "c_tsw":
                    theta[j] = gh.cover_transmission
                v = gh.parameters.get(p.name, {}).get("value")
                if v is not None:
                    theta[j] = v
            lo, hi = self.bounds(gh)
            theta = np.clip(theta, lo, hi)
        return theta

    def variations(self, gh: Greenhouse | None = None) -> np.ndarray:
        """Online variation ratios R_j (NaN where the whole box is searched)."""
        r = np.array([np.nan if p.variation is None else p.variation for p in self.parameters])
        if gh is not None:
            for j, p in enumerate(self.parameters):
                v = gh.parameters.get(p.name, {}).get("variation")
                if v is not None:
                    r[j] = v
        return r

    def with_terms(self, *terms: FluxTerm, name: str | None = None) -> Self:
        """This model plus extra terms (what the diagnosis does when it adds an effect)."""
        return replace(self, name=name or self.name, terms=self.terms + tuple(terms))

    def with_sensors(self, *sensors: SensorTerm) -> Self:
        """This model plus observation terms (sensor errors)."""
        return replace(self, sensors=self.sensors + tuple(sensors))

    def sensor_offset(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray],
                      t: Index) -> np.ndarray | float:
        """Measured minus true T_in [K] of the observation terms (0.0 when there are none)."""
        total: np.ndarray | float = 0.0
        for sensor in self.sensors:
            total = total + sensor.offset(p, x, t)
        return total

    def true_state(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray],
                   reading: np.ndarray, t: Index) -> np.ndarray:
        """The true T_in behind a ``reading`` at time ``t`` (the reading itself without sensor
        terms): where every run that starts from a measurement starts."""
        return reading - self.sensor_offset(p, x, t) if self.sensors else reading

    def reading(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray],
                state: np.ndarray, t: Index) -> np.ndarray:
        """What the sensor reads at time ``t`` for the true ``state`` (what is compared with the
        measurement)."""
        return state + self.sensor_offset(p, x, t) if self.sensors else state

    def columns(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Parameter matrix (P, k) → {name: column of shape (P, 1)}."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != len(self.parameters):
            raise ValueError(
                f"{self.name}: expected {len(self.parameters)} parameters {self.names}, "
                f"got {theta.shape[1]}"
            )
        rows = np.ascontiguousarray(theta.T)  # contiguous columns: faster element-wise steps
        return {n: rows[j, :, None] for j, n in enumerate(self.names)}

    # -- integration ------------------------------------------------------------------------
    def _sums(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray],
              terms: Sequence[FluxTerm]) -> stepping.Sums:
        """``sums(state, t) -> (g, s, k)`` over ``terms``: coefficients and slopes
        (``FluxTerm.linearised``; the coefficient s as slope when not re-linearised)."""
        if self.integration.relinearise:
            return _total([partial(term.linearised, p, x) for term in terms])
        return _total([partial(_frozen_slope(term), p, x) for term in terms])

    def prepare(self, x: Mapping[str, np.ndarray]) -> Mapping[str, np.ndarray]:
        """The drivers plus the terms' driver-only columns (``FluxTerm.derive``), computed once
        here rather than at every step for every candidate; ``x`` itself when they are there."""
        todo = [term for term in self.terms if any(k not in x for k in term.derives)]
        if not todo:
            return x
        out = dict(x)
        for term in todo:
            out.update(term.derive(x))
        return out

    def stepper(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray], c: float,
                dt: float) -> stepping.Stepper:
        """Steps of length ``dt`` [s] over the drivers ``x`` for the parameter columns ``p``:
        ``stepper(state, t)`` is :meth:`step`, and consecutive calls share the work of the
        terms that do not read the state (gateway/model/step.py)."""
        x = self.prepare(x)
        fixed = [term for term in self.terms if not term.state_dependent]
        moving = [term for term in self.terms if term.state_dependent]
        bind = None
        if self.integration.relinearise:

            def bind(rows: slice) -> stepping.RowSums:
                return _total([term.bind(p, x, rows) for term in moving])

        return stepping.Stepper(self._sums(p, x, fixed), self._sums(p, x, moving), c, dt,
                                len(x["t_out"]), self.integration, bind)

    def rates(
        self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray], t_in: np.ndarray,
        t: Index, c: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(dT_in/dt [K s-1], its slope λ = -∂/∂T_in [s-1]) at state ``t_in`` and time ``t``."""
        return self.stepper(p, x, c, 1.0).rates(t_in, t)

    def step(
        self,
        p: Mapping[str, np.ndarray],
        x: Mapping[str, np.ndarray],
        t_in: np.ndarray,
        t: Index,
        c: float,
        dt: float,
    ) -> np.ndarray:
        """One exponential step of length ``dt`` [s] from state ``t_in`` at time ``t``
        (gateway/model/step.py): the drivers at t + 1 are read when they exist, otherwise (the
        end of ``x``, a gap) the drivers at t are held."""
        return self.stepper(p, x, c, dt)(t_in, t)

    def one_step(
        self, theta: np.ndarray, x: Mapping[str, np.ndarray], gh: Greenhouse, dt: float
    ) -> np.ndarray:
        """One-step-ahead prediction (P, T): element t predicts T_in[t] from the measured
        T_in[t-1] and the inputs at t-1; column 0 is NaN."""
        p = self.columns(theta)
        measured = x["t_in"]
        c = self.capacity(gh)
        out = np.full((theta.shape[0] if theta.ndim == 2 else 1, len(measured)), np.nan)
        # Time blocks keep the (P, T) temporaries in cache and on the heap (step.BLOCK_ELEMENTS):
        # several times faster than one pass over the whole series at P = 100, T = 2880.
        block = max(16, stepping.BLOCK_ELEMENTS // out.shape[0])
        step = self.stepper(p, x, c, dt)
        for a in range(0, len(measured) - 1, block):
            b = min(a + block, len(measured) - 1)
            # restart from the true state behind the reading, report a reading
            prev = self.true_state(p, x, measured[None, a:b], slice(a, b))
            new = step(prev, slice(a, b))
            out[:, a + 1 : b + 1] = self.reading(p, x, new, slice(a + 1, b + 1))
        return out

    def free_run(
        self,
        theta: np.ndarray,
        x: Mapping[str, np.ndarray],
        gh: Greenhouse,
        dt: float,
        start: int = 0,
        stop: int | None = None,
        restart_after_gaps: bool = True,
    ) -> np.ndarray:
        """Simulation (P, stop-start) from the measured state at ``start``.

        Where an input is missing the state cannot be propagated: with ``restart_after_gaps``
        the run restarts from the next measured state (the gap itself stays NaN).
        """
        p = self.columns(theta)
        measured = x["t_in"]
        stop = len(measured) if stop is None else stop
        c = self.capacity(gh)
        n_p = next(iter(p.values())).shape[0]
        out = np.full((n_p, stop - start), np.nan)
        # sensor terms: integrate the true state, report a reading
        out[:, 0] = measured[start]
        state = self.true_state(p, x, np.full((n_p, 1), measured[start]), start)
        step = self.stepper(p, x, c, dt)
        for k, t in enumerate(range(start, stop - 1), start=1):
            state = step(state, t)
            out[:, k] = self.reading(p, x, state, t + 1)[:, 0]
            if restart_after_gaps and np.isnan(state[0, 0]):
                # The output stays NaN: a measurement copied into it would score as a perfect
                # prediction. The state restarts from the measurement when there is one.
                state = self.true_state(p, x, np.full((n_p, 1), measured[t + 1]), t + 1)
        return out

    def forecast(
        self,
        theta_rows: np.ndarray,
        x: Mapping[str, np.ndarray],
        gh: Greenhouse,
        dt: float,
        starts: np.ndarray,
        horizon: int,
    ) -> np.ndarray:
        """Free runs of ``horizon`` steps from many start times at once.

        ``theta_rows`` (N, k) holds the parameters in force at each start (N,). Returns (N,)
        predictions of T_in[start + horizon] from the measured T_in[start]. Vectorised over the
        starts: one Python iteration per step of the horizon, not per start.
        """
        return self.forecast_each(theta_rows, x, gh, dt, starts, [horizon])[horizon]

    def forecast_each(self, theta_rows: np.ndarray, x: Mapping[str, np.ndarray], gh: Greenhouse,
                      dt: float, starts: np.ndarray, horizons: Sequence[int]) -> dict[int, np.ndarray]:
        """{h: ``forecast`` of horizon h} for each of ``horizons``: one run to the longest, read
        at each on the way (the shorter runs are its first steps: the same numbers)."""
        p = self.columns(theta_rows)
        t = np.asarray(starts)[:, None]
        state = self.true_state(p, x, x["t_in"][t], t)
        step = self.stepper(p, x, self.capacity(gh), dt)
        out, done = {}, 0  # done: the steps taken
        for h in sorted(set(horizons)):
            for k in range(done, h):
                state = step(state, t + k)
            done = max(done, h)
            out[h] = self.reading(p, x, state, t + h)[:, 0]
        return out

    def fluxes(
        self, theta: np.ndarray, x: Mapping[str, np.ndarray], t_in: np.ndarray
    ) -> dict[str, np.ndarray]:
        """Each term's flux [W m-2] along a state trajectory ``t_in`` (T,) for one parameter
        vector (k,) or one per time step (T, k)."""
        theta = np.asarray(theta, dtype=float)
        if theta.ndim == 1:
            p = {k: v[:, 0] for k, v in self.columns(theta[None, :]).items()}
        else:
            p = {n: theta[:, j] for j, n in enumerate(self.names)}
        t = slice(0, len(t_in))
        return {term.name: term.flux(p, x, t_in, t) for term in self.terms}

    def fluxes_at(self, theta: np.ndarray, row: Mapping[str, float], t_in: float) -> dict[str, float]:
        """Each term's flux [W m-2] on one minute's drivers ``row`` (prepared, as an online
        estimator's ``last_row``) at the inside temperature ``t_in`` [°C]: what the live gateway
        publishes and a virtual sensor reads. {} when a driver is missing or a flux is not finite
        (nothing to say for that minute)."""
        x = {k: np.array([v], dtype=float) for k, v in row.items()}
        try:
            q = self.fluxes(theta, x, np.array([t_in], dtype=float))
        except KeyError:
            return {}
        out = {k: float(np.asarray(v).reshape(-1)[0]) for k, v in q.items()}
        return out if all(np.isfinite(v) for v in out.values()) else {}


def _total(
    fns: Sequence[Callable[[np.ndarray, IndexT], tuple]],
) -> Callable[[np.ndarray, IndexT], tuple]:
    """``sums(state, t)``: the (g, s, k) of ``fns`` (each ``fn(state, t)``) added in order."""
    if not fns:
        return lambda t_in, t: (0.0, 0.0, 0.0)
    first, rest = fns[0], fns[1:]
    if not rest:  # nothing to add: the one term's own (g, s, k), one call less per use
        return first

    def sums(t_in: np.ndarray, t: IndexT) -> tuple:
        g_sum, s_sum, k_sum = first(t_in, t)
        for fn in rest:
            g, s, k = fn(t_in, t)
            g_sum, s_sum, k_sum = g_sum + g, s_sum + s, k_sum + k
        return g_sum, s_sum, k_sum

    return sums


def _frozen_slope(term: FluxTerm) -> Callable:
    """``term.linearised`` with the coefficient s as the slope (the step before issue 10)."""

    def linearised(p, x, t_in, t):
        g, s = term.coefficients(p, x, t_in, t)
        return g, s, s

    return linearised


def check_columns(model: Model, available: Sequence[str], source: str) -> None:
    """Raise a clear error when the data lacks a column the model needs."""
    missing = [c for c in model.requires if c not in available]
    if missing:
        raise ValueError(
            f"{source}: the '{model.name}' model needs column(s) {', '.join(missing)} "
            f"(see docs/data-format.md)"
        )

"""A climate model as a list of flux terms, integrated with the exact exponential step.

``C dT_in/dt = sum_k (g_k - s_k T_in)``; with the coefficients frozen over one step of length
dt the solution is exact (docs/model-notes.md §4):

    T+ = T + (G - S T) dt/C * phi(S dt / C),   phi(z) = (1 - exp(-z)) / z

which equals ``T_eq + (T - T_eq) exp(-S dt/C)`` with ``T_eq = G/S`` and stays finite as S → 0.
It is unconditionally stable, so the stiff coefficients of table 13 (C_cnd_cnv up to
300 W m-2 K-1) are safe at a 60 s step where explicit Euler diverges.

Both evaluation modes take parameters of shape (P, k) and return predictions of shape (P, T)
with no Python loop over P.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model.terms import FluxTerm, Index, Parameter, SensorTerm


@dataclass(frozen=True)
class RadiationSubmodel:
    """Inside short-wave radiation ``i_in = c_tsw * i_glob`` (III.35), fitted on measured i_in."""

    parameter: Parameter
    equation: str = "III.35"

    def predict(self, c_tsw: np.ndarray, x: Mapping[str, np.ndarray]) -> np.ndarray:
        """i_in [W m-2] for c_tsw of shape (P, 1) → (P, T)."""
        return c_tsw * x["i_glob"]


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
        for term in (*self.terms, *self.sensors):
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

    def with_terms(self, *terms: FluxTerm, name: str | None = None) -> Model:
        """This model plus extra terms (what the diagnosis does when it adds an effect)."""
        return replace(self, name=name or self.name, terms=self.terms + tuple(terms))

    def with_sensors(self, *sensors: SensorTerm) -> Model:
        """This model plus observation terms (sensor errors)."""
        return replace(self, sensors=self.sensors + tuple(sensors))

    def sensor_offset(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray], t: Index):
        """Measured minus true T_in [K] of the observation terms (0.0 when there are none)."""
        total = 0.0
        for sensor in self.sensors:
            total = total + sensor.offset(p, x, t)
        return total

    def columns(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Parameter matrix (P, k) → {name: column of shape (P, 1)}."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != len(self.parameters):
            raise ValueError(
                f"{self.name}: expected {len(self.parameters)} parameters {self.names}, "
                f"got {theta.shape[1]}"
            )
        return {n: theta[:, j : j + 1] for j, n in enumerate(self.names)}

    # -- integration ------------------------------------------------------------------------
    def step(
        self,
        p: Mapping[str, np.ndarray],
        x: Mapping[str, np.ndarray],
        t_in: np.ndarray,
        t: Index,
        c: float,
        dt: float,
    ) -> np.ndarray:
        """One exact exponential step of length ``dt`` [s] from state ``t_in`` at time ``t``."""
        g_sum = 0.0
        s_sum = 0.0
        for term in self.terms:
            g, s = term.coefficients(p, x, t_in, t)
            g_sum = g_sum + g
            s_sum = s_sum + s
        # z >= 0; below 1e-12 phi = 1 - z/2 + ... is 1 to double precision, so clamping is exact
        z = np.maximum(s_sum * (dt / c), 1e-12)
        phi = -np.expm1(-z) / z
        return t_in + (g_sum - s_sum * t_in) * (dt / c) * phi

    def one_step(
        self, theta: np.ndarray, x: Mapping[str, np.ndarray], gh: Greenhouse, dt: float
    ) -> np.ndarray:
        """One-step-ahead prediction (P, T): element t predicts T_in[t] from the measured
        T_in[t-1] and the inputs at t-1; column 0 is NaN."""
        p = self.columns(theta)
        measured = x["t_in"]
        c = self.capacity(gh)
        out = np.full((theta.shape[0] if theta.ndim == 2 else 1, len(measured)), np.nan)
        # Time blocks of ~16k elements keep the (P, T) temporaries in cache: ~5x faster than
        # one pass over the whole series at P = 100, T = 2880.
        block = max(16, 16384 // out.shape[0])
        for a in range(0, len(measured) - 1, block):
            b = min(a + block, len(measured) - 1)
            if self.sensors:  # restart from the true state behind the reading, report a reading
                prev = measured[None, a:b] - self.sensor_offset(p, x, slice(a, b))
                new = self.step(p, x, prev, slice(a, b), c, dt)
                out[:, a + 1 : b + 1] = new + self.sensor_offset(p, x, slice(a + 1, b + 1))
            else:
                out[:, a + 1 : b + 1] = self.step(p, x, measured[None, a:b], slice(a, b), c, dt)
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
        obs = bool(self.sensors)  # sensor terms: integrate the true state, report a reading
        state = np.full((n_p, 1), measured[start])
        out[:, 0] = state[:, 0]
        if obs:
            state = state - self.sensor_offset(p, x, start)
        for k, t in enumerate(range(start, stop - 1), start=1):
            state = self.step(p, x, state, t, c, dt)
            out[:, k] = (state + self.sensor_offset(p, x, t + 1))[:, 0] if obs else state[:, 0]
            if restart_after_gaps and np.isnan(state[0, 0]):
                # The output stays NaN: a measurement copied into it would score as a perfect
                # prediction. The state restarts from the measurement when there is one.
                state = np.full((n_p, 1), measured[t + 1])
                if obs:
                    state = state - self.sensor_offset(p, x, t + 1)
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
        p = self.columns(theta_rows)
        c = self.capacity(gh)
        t = np.asarray(starts)[:, None]
        state = x["t_in"][t]
        if self.sensors:
            state = state - self.sensor_offset(p, x, t)
        for k in range(horizon):
            state = self.step(p, x, state, t + k, c, dt)
        if self.sensors:
            state = state + self.sensor_offset(p, x, t + horizon)
        return state[:, 0]

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


def check_columns(model: Model, available: Sequence[str], source: str) -> None:
    """Raise a clear error when the data lacks a column the model needs."""
    missing = [c for c in model.requires if c not in available]
    if missing:
        raise ValueError(
            f"{source}: the '{model.name}' model needs column(s) {', '.join(missing)} "
            f"(see docs/data-format.md)"
        )

"""Structural calibration of the base model before any effect is searched (issue 4, diagnosis).

The thesis models lump the greenhouse into one air node whose heat capacity is the air's alone
(C_ter = c_p ρ V / A, III.24). Real houses store heat in fast mass (crop, frame, pots, the floor's
skin) and release it with a lag (the floor and soil after sunset). On data richer than the model
that structural error is as large as the effects the diagnosis looks for, and an effect library
will happily "explain" it with a constant thermal-mass change or a heater. So the diagnosis fits
a slightly richer *base* on the calibration part first (docs/effects.md, "Base structure"):

- ``m_cap`` [-]: effective heat capacity of the air node = m_cap × C_model (air + fast mass);
- a lumped heat store (floor surface, soil, structure) coupled to the air, for models that do
  not read a measured soil temperature:

      C_s dT_s/dt = a_s I_glob + h_s (T_in - T_s) + k_s (T_out - T_s)
      Q_store = h_s (T_s - T_in)                        (into the air, W m-2 of floor)

  It is a second state. T_s is never measured, so wherever a run starts from a measured air
  temperature the store starts from an observer: the same store equation driven by the
  *measured* air temperature before that time (causal: it uses no later reading;
  store_observer.py);
- ``c_lw_sky`` [W m-2 K-1]: long-wave loss to the sky (as III.21) for models without one;
  for models with their own (the prototype's III.21 scales it by the wind-driven h_o) the search
  tries it as an optional part (search.calibrate_base): a night-time deficit carried by a flux
  shrinks when the air exchange grows, one carried by a sensor offset does not;
- ``c_sky_night`` [-]: the night cloud fraction of the site, fitted in place of the prior the
  kit's carried night cloud relaxes to (night_sky.py; every term reading T_sky sees it).

Effects are then *changes* from a time τ on top of this base: a thermal-mass effect is the
capacity factor changing, not the capacity being wrong from the start. Relative parameter
changes (cover transmission, capacity) are :class:`Modulation` s of base parameters.

All methods are vectorised over candidate parameter sets (rows) as in :mod:`gateway.model`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from gateway.diagnose import hoisted, recomputed, store_observer
from gateway.diagnose.layout import layout
from gateway.diagnose.night_sky import LEVEL, NightSky
from gateway.diagnose.store_observer import gaps_bridged
from gateway.greenhouse import Greenhouse
from gateway.model import psychrometrics as psy
from gateway.model import step as stepping
from gateway.model.model import Model
from gateway.model.terms import ALWAYS, FluxTerm, Index, Parameter, SensorTerm

if TYPE_CHECKING:
    from gateway.diagnose.heat_store import AddedStore

INDEX = "_index"
"""Driver holding each sample's time [s since the first sample] (fit.drivers), so τ survives
slicing of the drivers."""

CAPACITY = Parameter("m_cap", "-", 1.0, 12.0, 1.0, None, ALWAYS,
                     "effective heat capacity of the air node / air alone (fast mass: crop, frame)")
STORE = (
    Parameter("c_store", "J m-2 K-1", 5e3, 4e5, 5e4, None, ALWAYS,
              "heat capacity of the lumped store (floor surface, soil, structure)"),
    Parameter("h_store", "W m-2 K-1", 0.0, 25.0, 0.0, None, ALWAYS, "store–air coupling"),
    Parameter("k_store", "W m-2 K-1", 0.0, 25.0, 2.0, None, ALWAYS,
              "store loss to the outside (ground, long wave through the cover)"),
    Parameter("a_store", "-", 0.0, 1.0, 0.0, None, ALWAYS,
              "share of the outside radiation absorbed by the store"),
)
SKY = Parameter("c_lw_sky", "W m-2 K-1", 0.0, 15.0, 0.0, None, ALWAYS,
                "long-wave loss of the air node to the sky (III.21 form)")
SKY_TERMS = ("q_thermal",)
"""Base terms that already carry a long-wave loss to the sky (the prototype's III.21)."""
SOLAR_PARAMETERS = ("c_tsw", "c_solar", "a_store")
"""Parameters scaled by a change of cover transmission (whichever the model has)."""


def physical_capacity(gh: Greenhouse) -> float:
    """C_phys = c_p ρ V / A [J m-2 K-1] (III.24)."""
    return psy.CP_AIR * gh.air_density * gh.volume / gh.floor_area


def model_unit(model: Model, gh: Greenhouse) -> float:
    """u = C_model / C_phys: a physical flux [W m-2] times u is in the model's own units (1 for
    Almería, 1/c_p for the prototype whose lumped coefficients carry 1/C_a, III.14)."""
    return model.capacity(gh) / physical_capacity(gh)


def on(p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray], t: Index, tau: str) -> np.ndarray:
    """1.0 from the start sample τ on, else 0.0; shape broadcasts (P, 1) against time."""
    return (x[INDEX][t] >= p[tau]).astype(float)


class SkyLoss(FluxTerm):
    """Long-wave loss to the sky ``Q = c_lw_sky (T_sky - T_in)`` (III.21 form, T_sky III.13)."""

    name = "q_lw_sky"
    equation = "III.21 form"
    description = "long-wave loss to the sky: -c_lw_sky (T_in - T_sky)"
    requires = ("t_out",)
    optional = ("rh_out",)  # T_sky's clear-sky emissivity (gateway/model/sky.py)
    parameters = (SKY,)
    state_dependent = False

    def __init__(self, unit: float) -> None:
        self.unit = unit

    def coefficients(self, p, x, t_in, t: Index):
        s = self.unit * p["c_lw_sky"]
        return s * x["t_sky"][t], s


@dataclass(frozen=True)
class Modulation:
    """A relative change of base parameters from τ: ``p_j → p_j (1 + (A - A0) [t ≥ τ])``.

    ``A`` is the amplitude parameter, ``A0`` its neutral value (0 for a relative change, 1 for a
    factor). Used for a cover transmission change (solar parameters) and a change of thermal
    mass (``m_cap``).
    """

    name: str
    targets: tuple[str, ...]
    amp: Parameter
    tau: Parameter
    neutral: float

    @property
    def parameters(self) -> tuple[Parameter, Parameter]:
        return (self.amp, self.tau)

    def factor(self, p, x, t: Index) -> np.ndarray:
        return 1.0 + (p[self.amp.name] - self.neutral) * on(p, x, t, self.tau.name)


@dataclass(frozen=True)
class Structured(Model):
    """A base model with an effective capacity, optionally a heat store, and modulations.

    Same API as :class:`Model` (``one_step``, ``free_run``, ``forecast``) plus :meth:`shoot`,
    free runs from many start times for many parameter sets at once.
    """

    store: bool = False
    modulations: tuple[Modulation, ...] = ()
    night_sky: NightSky | None = None
    added: AddedStore | None = None
    """A heat store added from τ (heat_store.py): a third state, its own observer."""

    # -- building ----------------------------------------------------------------------------
    def with_modulation(self, m: Modulation) -> Structured:
        return replace(self, modulations=self.modulations + (m,), extra=self.extra + m.parameters)

    def with_store(self, store: AddedStore) -> Structured:
        """This model plus an added heat store (heat_store.py)."""
        return replace(self, added=store, extra=self.extra + store.parameters)

    def with_night_sky(self, lower: float = LEVEL.lower, upper: float = LEVEL.upper) -> Structured:
        """The night sky level fitted as a base parameter (night_sky.py), within the bounds."""
        ns = NightSky(lower, upper)
        return replace(self, night_sky=ns, extra=self.extra + ns.parameters)

    # -- parameters at a time ------------------------------------------------------------------
    def _at(self, p: Mapping[str, np.ndarray], x, t: Index) -> Mapping[str, np.ndarray]:
        """The parameters in force at ``t`` (``p`` itself, not a copy, without modulations:
        the caller only reads them)."""
        if not self.modulations:
            return p
        q = dict(p)
        for m in self.modulations:
            f = m.factor(p, x, t)
            for name in m.targets:
                if name in q:
                    q[name] = q[name] * f
        return q

    # -- one step of the two nodes ------------------------------------------------------------
    def _inputs(self, p, x, t: Index, given: Mapping[str, np.ndarray] | None = None):
        """The drivers as the terms see them at ``t`` (recomputed.inputs)."""
        return recomputed.inputs(self.night_sky, self.sensors, p, x, t, given)

    def advance(self, q, x, ta, ts, t: Index, c0: float, unit: float, dt: float,
                given: Mapping[str, np.ndarray] | None = None,
                air_dt: np.ndarray | None = None, plan: hoisted.Plan | None = None, k: int = 0):
        """Air (exponential step, stores frozen), then the store(s) (exponential steps, new
        air; ``ts`` is the pair (base store, added store) when there is an added one): the
        model layer's step (gateway/model/step.py) with the zero-order hold that the coarsened
        inputs are built for (fit.coarsen: block means of the inputs over each step).
        ``given``: drivers at ``t`` the caller already computed (``_inputs``); ``air_dt``:
        Δ / (c0 m_cap) [s m2 K J-1] when the caller holds it (``m_cap`` not modulated);
        ``plan``: the run's state-independent coefficients (hoisted.py), ``k`` its step."""
        x = self._inputs(q, x, t, given)
        g_sum, s_sum = (hoisted.unplanned(self.terms) if plan is None else plan).sums(
            k, q, x, ta, t)
        tw = None
        if self.added is not None:  # states (base store, added store)
            ts, tw = ts
            g, s = self.added.coefficients(q, x, tw, t, dt, unit)
            g_sum, s_sum = g_sum + g, s_sum + s
        if self.store:
            h = unit * q["h_store"]
            g_sum, s_sum = g_sum + h * ts, s_sum + h
        if air_dt is None:
            air_dt = dt / (c0 * q["m_cap"])
        ta_new = stepping.advance(ta, g_sum - s_sum * ta, s_sum, air_dt)
        if tw is not None and self.added is not None:  # tw is only set with an added store
            tw = self.added.step(q, x, tw, ta_new, t, dt)
        if not self.store:
            return ta_new, (ts if tw is None else (ts, tw))
        s_st = q["h_store"] + q["k_store"]
        g_st = q["a_store"] * x["i_glob"][t] + q["h_store"] * ta_new + q["k_store"] * x["t_out"][t]
        cs = q["c_store"]
        ts_new = stepping.advance(ts, g_st - s_st * ts, s_st, dt / cs)
        return ta_new, (ts_new if tw is None else (ts_new, tw))

    def _observed(self, p, x, dt: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The slow states (P, T) from their observers: base store, added store (or None)."""
        return (self.observer(p, x, dt) if self.store else None,
                self.added.observer(self, p, x, dt) if self.added is not None else None)

    def _slow_at(self, obs, idx, shape: tuple[int, ...] | None = None):
        """The slow states at ``idx`` as ``advance`` takes them (``shape``: reshaped to it,
        ``shoot``'s layout)."""
        at = [None if o is None else (o[:, idx] if shape is None else o[:, idx].reshape(shape))
              for o in obs]
        return at[0] if self.added is None else (at[0], at[1])

    # -- the store observer -------------------------------------------------------------------
    def observer(self, p: Mapping[str, np.ndarray], x, dt: float) -> np.ndarray:
        """Store temperature (P, T) driven by the measured air temperature: T_s[t] uses
        readings up to t only (the same exact step as ``advance``, with the reading in place
        of the simulated air; store_observer.py)."""
        idx = slice(0, len(x["t_in"]))
        ta = self.true_state(p, x, gaps_bridged(x["t_in"])[None, :], idx)
        return store_observer.observe(self._at(p, x, idx), x, ta, dt)

    # -- evaluation modes ---------------------------------------------------------------------
    def shoot(self, theta: np.ndarray, x, gh: Greenhouse, dt: float, starts: np.ndarray,
              horizon: int) -> np.ndarray:
        """Readings predicted at steps 1..H of free runs from every start, for every candidate:
        (P, N, H). One Python iteration per step serves candidates × starts (layout.py)."""
        theta = np.atleast_2d(theta)
        n_p, n = theta.shape[0], len(starts)
        p = self.columns(theta)
        c0, unit = self.capacity(gh), model_unit(self, gh)
        starts = np.asarray(starts, dtype=int)
        q0, t0, shape = layout(p, starts)
        ta = self.true_state(q0, x, x["t_in"][t0], t0)
        ts = self._slow_at(self._observed(p, x, dt), starts, shape)
        grid = shape != (n_p * n, 1)  # else rows: windows() repeats ``p`` per start itself
        pre = {name: v.reshape(-1, shape[1], horizon) for name, v in recomputed.windows(
            self.night_sky, self.sensors, self.modulations, q0 if grid else p, x, starts,
            horizon).items()}
        out = np.empty((n_p, n, horizon))
        dest = out.reshape(shape + (horizon,))  # a view: out in the state's layout
        air_dt = self._air_dt(q0, c0, dt)
        steps = self._steps(q0, x, np.arange(horizon)[:, None, None] + t0[None],
                            {name: v.transpose(2, 0, 1) for name, v in pre.items()}, not grid)
        for k, (plan, j, off) in zip(range(horizon), steps, strict=True):
            t = t0 + k
            q = self._at(q0, x, t)
            ta, ts = self.advance(q, x, ta, ts, t, c0, unit, dt,
                                  {name: v[:, :, k] for name, v in pre.items()} if pre
                                  else None, air_dt, plan, j)
            dest[:, :, k] = ta if off is None else ta + off
        return out

    def _steps(self, p, x, block: np.ndarray, given: Mapping[str, np.ndarray],
               planned: bool = True) -> Iterator[tuple[hoisted.Plan | None, int, Any]]:
        """For each step of a run, from the time indices of all of them ``block`` (steps, ...)
        and the parameters ``p`` as the run's state broadcasts them: the plan of the
        state-independent coefficients (hoisted.py; None when not ``planned``: a shooting
        grid, whose state-independent terms mostly read shared parameters, layout.py, ran
        faster without), the step's index in it, and the sensor offset at the step's end (None
        without sensor terms). ``given``: ``_inputs``'s, as blocks (steps, ...). Planned a
        chunk of steps at a time, whose temporaries of about step.BLOCK_ELEMENTS elements stay
        in cache and on the heap."""
        if not planned:
            for t in block:
                yield None, 0, self.sensor_offset(p, x, t + 1) if self.sensors else None
            return
        state = np.broadcast_shapes(block.shape[1:], *(v.shape for v in p.values()))
        size = max(1, stepping.BLOCK_ELEMENTS // math.prod(state))
        for a in range(0, len(block), size):
            t = block[a : a + size]
            q = self._at(p, x, t)
            plan = hoisted.plan(self.terms, q, self._inputs(
                q, x, t, {name: v[a : a + size] for name, v in given.items()}), t)
            off = hoisted.columns(self.sensor_offset(p, x, t + 1)) if self.sensors else None
            for j in range(len(t)):
                yield plan, j, None if off is None else off[j]

    def _air_dt(self, p: Mapping[str, np.ndarray], c0: float, dt: float) -> np.ndarray | None:
        """Δ / (c0 m_cap) for every step of a run (``advance``'s ``air_dt``), or None when a
        modulation changes ``m_cap`` (then each step computes its own)."""
        if any("m_cap" in m.targets for m in self.modulations):
            return None
        return dt / (c0 * p["m_cap"])

    def one_step(self, theta, x, gh, dt):
        """(P, T): element t predicts the reading at t from the reading at t-1 (store from the
        observer); column 0 is NaN."""
        theta = np.atleast_2d(theta)
        p = self.columns(theta)
        n = len(x["t_in"])
        c0, unit = self.capacity(gh), model_unit(self, gh)
        obs = self._observed(p, x, dt)
        out = np.full((theta.shape[0], n), np.nan)
        block = max(16, 16384 // theta.shape[0])
        for a in range(0, n - 1, block):
            b = min(a + block, n - 1)
            t = slice(a, b)
            ta = self.true_state(p, x, x["t_in"][None, a:b], t)
            ts = self._slow_at(obs, t)
            new, _ = self.advance(self._at(p, x, t), x, ta, ts, t, c0, unit, dt)
            out[:, a + 1 : b + 1] = self.reading(p, x, new, slice(a + 1, b + 1))
        return out

    def free_run(self, theta, x, gh, dt, start=0, stop=None, restart_after_gaps=True):
        """Simulation (P, stop-start) from the measured state at ``start`` (store from the
        observer); restarts from the next reading after an input gap (the gap stays NaN)."""
        theta = np.atleast_2d(theta)
        p = self.columns(theta)
        meas = x["t_in"]
        stop = len(meas) if stop is None else stop
        c0, unit = self.capacity(gh), model_unit(self, gh)
        obs = self._observed(p, x, dt)
        n_p = theta.shape[0]
        out = np.full((n_p, stop - start), np.nan)

        def restart(t: int):
            ta = self.true_state(p, x, np.full((n_p, 1), meas[t]), t)
            return ta, self._slow_at(obs, slice(t, t + 1))

        ta, ts = restart(start)
        out[:, 0] = meas[start]
        sky = None  # the fitted night sky's temperature at every step, computed once
        if self.night_sky is not None:
            recomputed.check_unmodulated(self.modulations, [LEVEL.name])
            sky = self.night_sky.t_sky(p, x, slice(start, stop - 1))  # (P, stop-1-start)
        steps = self._steps(p, x, np.arange(start, stop - 1)[:, None, None],
                            {} if sky is None else {"t_sky": sky.T[:, :, None]})
        for k, (t, (plan, j, off)) in enumerate(zip(range(start, stop - 1), steps, strict=True),
                                                start=1):
            ta, ts = self.advance(self._at(p, x, t), x, ta, ts, t, c0, unit, dt,
                                  None if sky is None else {"t_sky": sky[:, k - 1 : k]},
                                  None, plan, j)
            out[:, k] = (ta if off is None else ta + off)[:, 0]
            if restart_after_gaps and np.isnan(ta[0, 0]):
                ta, ts = restart(t + 1)
        return out

    def forecast(self, theta_rows, x, gh, dt, starts, horizon):
        """Free runs of ``horizon`` steps from many starts (one parameter row per start): (N,)."""
        starts = np.asarray(starts, dtype=int)
        out = np.empty(len(starts))
        for i, (row, s0) in enumerate(zip(np.atleast_2d(theta_rows), starts, strict=True)):
            out[i] = self.shoot(row[None, :], x, gh, dt, np.array([s0]), horizon)[0, 0, -1]
        return out


def structure(base: Model, gh: Greenhouse, store: bool) -> Structured:
    """The diagnosis's base: ``base`` + effective capacity, + sky loss when it has none, + a
    heat store when ``store`` (used when no soil temperature is measured)."""
    terms = tuple(base.terms)
    if not any(t.name in SKY_TERMS for t in terms):
        terms = terms + (SkyLoss(model_unit(base, gh)),)
    extra = tuple(base.extra) + (CAPACITY,) + (STORE if store else ())
    fields = {f: getattr(base, f) for f in ("name", "capacity", "radiation", "description",
                                             "capacity_equation", "online", "sensors")}
    # ``advance`` holds the inputs over each step, as fit.coarsen builds them
    return Structured(terms=terms, extra=extra, store=store, integration=stepping.FROZEN, **fields)


class SensorBias(SensorTerm):
    """A constant calibration offset of the inside sensor: ``T_meas = T + b`` (electronic: the
    RH channel refers to the true temperature, so the vapour pressure is recomputed). Bounded by
    what two low-cost sensors can disagree by (±0.5 K each): a wider offset trades against the
    sky loss and lets an effect move the night-time level it should not."""

    name = "e_sensor_bias"
    electronic = True
    description = "constant inside-sensor offset"
    parameters = (Parameter("b_sensor", "K", -1.0, 1.0, 0.0, None, ALWAYS,
                            "constant offset of the inside temperature reading"),)

    def offset(self, p, x, t: Index) -> np.ndarray:
        return p["b_sensor"] * np.ones_like(x[INDEX][t])

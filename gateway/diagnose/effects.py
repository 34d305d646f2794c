"""The effect library: physical effects a calibrated model may lack (issue 4, docs/effects.md).

Each effect is one term with a name, a physical meaning, one amplitude parameter (unit, hard
bounds, neutral value = "no effect") and a start time τ [s since the first sample] from which
it acts (τ = 0: it was there before the data began). Four kinds:

- ``flux``: a heat flux added to the air balance (a :class:`FluxTerm`);
- ``modulation``: a relative change of base parameters (cover transmission, heat capacity), see
  :class:`gateway.diagnose.structure.Modulation`;
- ``sensor``: an observation error (a :class:`SensorTerm`): the heat balance is unchanged, the
  reading is not;
- ``store``: a heat store added from τ and coupled to the air, a state of its own
  (:class:`gateway.diagnose.heat_store.AddedStore`; its coupling is a third parameter, refitted
  with the base).

Effects are *changes* on top of the structurally calibrated base (structure.py): the base
already has an effective heat capacity, so ``thermal_mass`` can only start inside the data.

Fluxes are converted to each model's own units through ``u = C_model / (c_p ρ V / A)`` (III.24):
the Almería model is in W m-2 (u = 1), the prototype's lumped coefficients carry 1/c_p (III.14).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from gateway.diagnose.evidence import NONE, Evidence
from gateway.diagnose.heat_store import AddedStore
from gateway.diagnose.humidity import DriftEvidence, HumidityEvidence
from gateway.diagnose.radiation import RadiationEvidence
from gateway.diagnose.structure import (
    INDEX,
    SOLAR_PARAMETERS,
    Modulation,
    Structured,
    model_unit,
    on,
)
from gateway.greenhouse import Greenhouse
from gateway.model.terms import ALWAYS, SUN_THRESHOLD, FluxTerm, Index, Parameter, SensorTerm


# -- flux terms ------------------------------------------------------------------------------
class ExtraVentilation(FluxTerm):
    """Added air exchange from τ (door left open, torn cover, extra leakage):
    ``Q = ρ c_p (V/A) (N/3600) (T_out - T_in)`` with N air changes per hour (III.32 form)."""

    equation = "ρ c_p V N (T_out - T_in) / A (III.32 form)"
    description = "added air exchange from τ"
    requires = ("t_out",)
    state_dependent = False

    def __init__(self, capacity: float, amp: Parameter, tau: Parameter) -> None:
        self.capacity, self.amp, self.tau = capacity, amp.name, tau.name
        self.name = "q_extra_ventilation"
        self.parameters = (amp, tau)

    def coefficients(self, p, x, t_in, t: Index):
        s = self.capacity * p[self.amp] / 3600.0 * on(p, x, t, self.tau)
        return s * x["t_out"][t], s


class HeatSource(FluxTerm):
    """An undeclared heat input ``Q = P`` [W m-2 floor] from τ (heater, warm-water pipe, a
    machine); ``night_only``: only while the outside radiation is below 5 W m-2."""

    equation = "P (W m-2 of floor)"
    requires = ("i_glob",)
    state_dependent = False

    def __init__(self, unit: float, amp: Parameter, tau: Parameter, night_only: bool) -> None:
        self.unit, self.amp, self.tau, self.night_only = unit, amp.name, tau.name, night_only
        self.name = "q_night_heat_source" if night_only else "q_heat_source"
        self.description = "undeclared heat input" + (" at night" if night_only else "")
        self.parameters = (amp, tau)

    def coefficients(self, p, x, t_in, t: Index):
        g = self.unit * p[self.amp] * on(p, x, t, self.tau)
        if self.night_only:
            g = g * (x["i_glob"][t] <= SUN_THRESHOLD)
        return g, 0.0


# -- sensor terms ----------------------------------------------------------------------------
class RadiationBias(SensorTerm):
    """Sun-heated inside sensor: ``T_meas = T + k I_glob`` from τ (k per outside W m-2)."""

    requires = ("i_glob",)
    description = "sensor reads k·I_glob too warm"

    def __init__(self, amp: Parameter, tau: Parameter) -> None:
        self.amp, self.tau = amp.name, tau.name
        self.name = "e_sensor_radiation_bias"
        self.parameters = (amp, tau)

    def offset(self, p, x, t: Index) -> np.ndarray:
        return p[self.amp] * x["i_glob"][t] * on(p, x, t, self.tau)


class Drift(SensorTerm):
    """Drifting sensor: ``T_meas = T + a (t - τ)`` for t ≥ τ, a in K per day.

    Electronic: the temperature reading drifts, the RH channel still refers to the true air
    temperature, so the inside vapour pressure is recomputed from the corrected reading
    (structure.Structured._inputs). A sun-heated sensor is not electronic: its RH refers to its
    own warm body, so reading and RH give the true vapour pressure together.
    """

    description = "sensor reading drifts linearly"
    electronic = True

    def __init__(self, amp: Parameter, tau: Parameter) -> None:
        self.amp, self.tau = amp.name, tau.name
        self.name = "e_sensor_drift"
        self.parameters = (amp, tau)

    def offset(self, p, x, t: Index) -> np.ndarray:
        return p[self.amp] * np.maximum(x[INDEX][t] - p[self.tau], 0.0) / 86400.0


# -- the library -----------------------------------------------------------------------------
Part = FluxTerm | Modulation | SensorTerm | AddedStore
Make = Callable[["Effect", Structured, Greenhouse, Parameter, Parameter], Part]
PartT = TypeVar("PartT", FluxTerm, Modulation, SensorTerm, AddedStore)


def part_as(e: Effect, part: Part, cls: type[PartT]) -> PartT:
    """``part`` (built by ``e``) as the class its ``kind`` says it is."""
    if not isinstance(part, cls):
        raise TypeError(f"effect {e.name} (kind {e.kind}) built a {type(part).__name__}, "
                        f"not a {cls.__name__}")
    return part


@dataclass(frozen=True)
class Effect:
    """A library entry: name, kind, meaning, amplitude parameter, how to build its part of the
    model (``make``) and what a second output says about it (``evidence``)."""

    name: str
    kind: str  # "flux" | "modulation" | "sensor" | "store"
    meaning: str
    signature: str
    amp_name: str
    unit: str
    lower: float
    upper: float
    neutral: float
    describe: Callable[[float], str]
    """Amplitude → a short phrase, e.g. ``"solar gain fell 31 %"``."""
    make: Make
    """(effect, base model, greenhouse, amplitude parameter, start parameter) → its part."""
    from_start: bool = True
    """May the effect act from the first sample (τ = 0)? False when the base structure already
    holds its constant version (a capacity change must start inside the data)."""
    evidence: Evidence = NONE
    """The second output that must bear the effect out too (radiation.py, humidity.py)."""

    def parameters(self, duration: float) -> tuple[Parameter, Parameter]:
        amp = Parameter(self.amp_name, self.unit, self.lower, self.upper, self.neutral, None,
                        ALWAYS, self.meaning)
        tau = Parameter(self.tau_name, "s", 0.0, max(duration, 1.0), 0.0, None, ALWAYS,
                        f"start of {self.name} [s since the first sample]")
        return amp, tau

    @property
    def tau_name(self) -> str:
        return f"tau_{self.name}"

    def build(self, model: Structured, gh: Greenhouse, duration: float) -> Part:
        """The term, modulation or sensor term of this effect for ``model``."""
        amp, tau = self.parameters(duration)
        return self.make(self, model, gh, amp, tau)


def _solar(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
    targets = tuple(n for n in SOLAR_PARAMETERS if n in model.names)
    if model.radiation is not None:  # c_tsw carries every solar path (III.35)
        targets = tuple(n for n in targets if n != "c_solar")
    return Modulation(e.name, targets, amp, tau, e.neutral)


def _capacity(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
    return Modulation(e.name, ("m_cap",), amp, tau, e.neutral)


def _store(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
    return AddedStore(e.name, amp, tau)


def _exchange(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
    return ExtraVentilation(model.capacity(gh), amp, tau)


def _heat(night_only: bool) -> Make:
    def make(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
        return HeatSource(model_unit(model, gh), amp, tau, night_only=night_only)

    return make


def _sun_sensor(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
    return RadiationBias(amp, tau)


def _drift(e: Effect, model: Structured, gh: Greenhouse, amp: Parameter, tau: Parameter) -> Part:
    return Drift(amp, tau)


def _pct(word_up: str, word_down: str) -> Callable[[float], str]:
    return lambda a: f"{word_up if a >= 0 else word_down} {abs(a) * 100:.0f} %"


LIBRARY: tuple[Effect, ...] = (
    Effect("solar_gain_change", "modulation",
           "step change of the cover's solar transmission (whitening, shading, second cover, "
           "dust): every solar gain of the model scaled by 1 + d",
           "daytime residual proportional to radiation, lagging it when mass stores the sun",
           "d_solar", "-", -0.9, 1.5, 0.0, _pct("solar gain rose", "solar gain fell"), _solar,
           evidence=RadiationEvidence()),
    Effect("extra_ventilation", "flux",
           "added air exchange (door left open, torn cover, extra leakage)",
           "residual proportional to T_in - T_out (pulls towards outside), day and night",
           "n_extra", "h-1", 0.0, 60.0, 0.0, lambda a: f"{a:.2g} extra air changes per hour",
           _exchange, evidence=HumidityEvidence()),
    Effect("heat_source", "flux",
           "undeclared constant heat input (heater, warm pipe, machine)",
           "warm offset at all hours, largest at night when the house is closed",
           "p_heat", "W m-2", 0.0, 400.0, 0.0, lambda a: f"{a:.3g} W m-2 of heat added",
           _heat(night_only=False)),
    Effect("night_heat_source", "flux",
           "undeclared heat input at night only (night heater, night screen heating)",
           "warm offset at night only",
           "p_night_heat", "W m-2", 0.0, 400.0, 0.0,
           lambda a: f"{a:.3g} W m-2 of heat added at night", _heat(night_only=True)),
    Effect("thermal_mass", "modulation",
           "change of the heat capacity coupled to the air (water barrels, concrete, more crop)",
           "damped, lagging daily swing: residual opposite to dT/dt",
           "m_capacity", "-", 0.25, 8.0, 1.0, lambda a: f"heat capacity x {a:.2f}", _capacity,
           from_start=False),
    Effect("sensor_radiation_bias", "sensor",
           "inside sensor heated by the sun (missing or poor radiation shield)",
           "reading too warm in proportion to radiation, no lag, zero at night",
           "k_rad", "K W-1 m2", 0.0, 0.03, 0.0,
           lambda a: f"sensor reads {a * 1000:.2f} mK per W m-2 too warm", _sun_sensor),
    Effect("sensor_drift", "sensor",
           "drifting inside temperature sensor (ageing, contamination)",
           "residual growing linearly with time",
           "a_drift", "K d-1", -3.0, 3.0, 0.0, lambda a: f"sensor drifts {a:+.3g} K per day",
           _drift, from_start=False, evidence=DriftEvidence()),
)
HEAT_STORE = Effect(
    "heat_store_added", "store",
    "a heat store added and coupled to the air (water barrels or tanks, a concrete floor or "
    "wall): C_w dT_w/dt = h_w (T_in - T_w), filled at the air's temperature",
    "damped daily swing with a lag of hours: residual opposite to dT/dt, smoothed",
    "c_added", "J m-2 K-1", 0.0, 4e5, 0.0,
    lambda a: f"heat store of {a / 1e3:.3g} kJ m-2 K-1 added (≈ {a / 4186:.2g} kg m-2 of water)",
    _store, from_start=False)
"""The added heat store (heat_store.py), beside ``thermal_mass`` (a capacity factor): it names
the same kind of change (docs/effects.md, "An added heat store")."""
OFFER_HEAT_STORE = False
"""Whether LIBRARY holds ``HEAT_STORE`` (read at import; at run time pass
``library=LIBRARY + (HEAT_STORE,)`` to ``diagnose``). Off: on the tuning generators it gained no
``thermal_mass`` case, changed no verdict and cost × 1.16 CPU, against the rule declared before
(docs/effects.md, "An added heat store"); the effect stays available."""
if OFFER_HEAT_STORE:
    LIBRARY = LIBRARY + (HEAT_STORE,)
EFFECTS = {e.name: e for e in (*LIBRARY, HEAT_STORE)}


def compose(base: Structured, effects: list[Effect], gh: Greenhouse, duration: float) -> Structured:
    """Base model plus effect terms: flux terms, modulations, added stores, sensor terms."""
    model = base
    for e in effects:
        part = e.build(base, gh, duration)
        if e.kind == "flux":
            model = model.with_terms(part_as(e, part, FluxTerm))
        elif e.kind == "modulation":
            model = model.with_modulation(part_as(e, part, Modulation))
        elif e.kind == "store":
            model = model.with_store(part_as(e, part, AddedStore))
        else:
            model = model.with_sensors(part_as(e, part, SensorTerm))
    return model

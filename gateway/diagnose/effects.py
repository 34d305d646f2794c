"""The effect library: physical effects a calibrated model may lack (issue 4, docs/effects.md).

Each effect is one term with a name, a physical meaning, one amplitude parameter (unit, hard
bounds, neutral value = "no effect") and a start time τ [sample index] from which it acts
(τ = 0: it was there before the data began). Three kinds:

- ``flux``: a heat flux added to the air balance (a :class:`FluxTerm`);
- ``capacity``: a change of the air node's heat capacity, written as a flux term that rescales
  the others (exact for the exponential step, see :class:`CapacityChange`);
- ``sensor``: an observation error (a :class:`SensorTerm`): the heat balance is unchanged, the
  reading is not.

Fluxes are converted to each model's own units through the capacity ratio
``u = C_model / C_phys`` with ``C_phys = c_p ρ V / A`` [J m-2 K-1] (III.24): the Almería model is
in W m-2 (u = 1), the prototype's lumped coefficients carry 1/c_p (III.14, u = 1/c_p).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import psychrometrics as psy
from gateway.model.model import Model
from gateway.model.terms import ALWAYS, SUN_THRESHOLD, FluxTerm, Index, Parameter, SensorTerm

INDEX = "_index"
"""Driver holding the absolute sample index (float), so τ survives slicing of the drivers."""


def _on(p, x, t: Index, tau: str) -> np.ndarray:
    """1.0 from the start sample τ on, else 0.0; shape broadcasts (P, 1) against time."""
    return (x[INDEX][t] >= p[tau]).astype(float)


def physical_capacity(gh: Greenhouse) -> float:
    """C_phys = c_p ρ V / A [J m-2 K-1] (III.24)."""
    return psy.CP_AIR * gh.air_density * gh.volume / gh.floor_area


# -- flux terms ------------------------------------------------------------------------------
class SolarGainChange(FluxTerm):
    """Step change of the solar gain: ``Q = δ · Q_solar(base)`` from τ (cover transmission
    change: whitening, shading screen, second cover, dust). δ = -0.31 means "fell 31 %"."""

    equation = "δ Q_solar (III.15 / III.25)"
    description = "relative change of the solar gain from τ"
    requires = ("i_glob",)

    def __init__(self, base: FluxTerm, amp: Parameter, tau: Parameter) -> None:
        self.base, self.amp, self.tau = base, amp.name, tau.name
        self.name = "q_solar_gain_change"
        self.parameters = (amp, tau)
        self.uses = tuple(q.name for q in base.parameters) + base.uses

    def coefficients(self, p, x, t_in, t: Index):
        g, _ = self.base.coefficients(p, x, t_in, t)
        return p[self.amp] * _on(p, x, t, self.tau) * g, 0.0


class ExtraVentilation(FluxTerm):
    """Added air exchange from τ (door left open, torn cover, extra leakage):
    ``Q = -C (N/3600) (T_in - T_out)`` with N air changes per hour."""

    equation = "ρ c_p V N (T_out - T_in) / A (III.32 form)"
    description = "added air exchange from τ"
    requires = ("t_out",)

    def __init__(self, capacity: float, amp: Parameter, tau: Parameter) -> None:
        self.capacity, self.amp, self.tau = capacity, amp.name, tau.name
        self.name = "q_extra_ventilation"
        self.parameters = (amp, tau)

    def coefficients(self, p, x, t_in, t: Index):
        s = self.capacity * p[self.amp] / 3600.0 * _on(p, x, t, self.tau)
        return s * x["t_out"][t], s


class HeatSource(FluxTerm):
    """An undeclared heat input ``Q = P`` [W m-2 floor] from τ (heater, warm-water pipe, a
    machine); ``night_only``: only while the outside radiation is below 5 W m-2."""

    equation = "P (W m-2 of floor)"
    requires = ("i_glob",)

    def __init__(self, unit: float, amp: Parameter, tau: Parameter, night_only: bool) -> None:
        self.unit, self.amp, self.tau, self.night_only = unit, amp.name, tau.name, night_only
        self.name = "q_night_heat_source" if night_only else "q_heat_source"
        self.description = "undeclared heat input" + (" at night" if night_only else "")
        self.parameters = (amp, tau)

    def coefficients(self, p, x, t_in, t: Index):
        g = self.unit * p[self.amp] * _on(p, x, t, self.tau)
        if self.night_only:
            g = g * (x["i_glob"][t] <= SUN_THRESHOLD)
        return g, 0.0


class CapacityChange(FluxTerm):
    """Heat capacity of the air node × m from τ (water barrels, a concrete floor, a denser
    crop: mass tightly coupled to the air). ``m C dT/dt = G - S T`` is the same as adding
    ``-(1 - 1/m)(G - S T)`` to the unscaled balance, so this term rescales the sum (G, S) of
    the ``wrapped`` terms and the exponential step stays exact."""

    equation = "m C_ter dT/dt (III.24)"
    description = "change of the air node's heat capacity from τ"

    def __init__(self, wrapped: tuple[FluxTerm, ...], amp: Parameter, tau: Parameter) -> None:
        self.wrapped, self.amp, self.tau = wrapped, amp.name, tau.name
        self.name = "q_thermal_mass"
        self.parameters = (amp, tau)
        self.requires = tuple(dict.fromkeys(c for w in wrapped for c in w.requires))

    def coefficients(self, p, x, t_in, t: Index):
        g_sum, s_sum = 0.0, 0.0
        for w in self.wrapped:
            g, s = w.coefficients(p, x, t_in, t)
            g_sum, s_sum = g_sum + g, s_sum + s
        f = (1.0 - 1.0 / p[self.amp]) * _on(p, x, t, self.tau)
        return -f * g_sum, -f * s_sum


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
        return p[self.amp] * x["i_glob"][t] * _on(p, x, t, self.tau)


class Drift(SensorTerm):
    """Drifting sensor: ``T_meas = T + a (t - τ)`` for t ≥ τ, a in K per day."""

    description = "sensor reading drifts linearly"

    def __init__(self, dt: float, amp: Parameter, tau: Parameter) -> None:
        self.dt, self.amp, self.tau = dt, amp.name, tau.name
        self.name = "e_sensor_drift"
        self.parameters = (amp, tau)

    def offset(self, p, x, t: Index) -> np.ndarray:
        days = np.maximum(x[INDEX][t] - p[self.tau], 0.0) * (self.dt / 86400.0)
        return p[self.amp] * days


# -- the library -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Effect:
    """A library entry: name, kind, meaning, amplitude parameter, and how to build its term."""

    name: str
    kind: str  # "flux" | "capacity" | "sensor"
    meaning: str
    signature: str
    amp_name: str
    unit: str
    lower: float
    upper: float
    neutral: float
    describe: Callable[[float], str]
    """Amplitude → a short phrase, e.g. ``"solar gain fell 31 %"``."""

    def parameters(self, n: int) -> tuple[Parameter, Parameter]:
        amp = Parameter(self.amp_name, self.unit, self.lower, self.upper, self.neutral, None,
                        ALWAYS, self.meaning)
        tau = Parameter(self.tau_name, "sample", 0.0, float(max(n - 1, 1)), 0.0, None, ALWAYS,
                        f"start of {self.name} [sample index]")
        return amp, tau

    @property
    def tau_name(self) -> str:
        return f"tau_{self.name}"

    def build(self, model: Model, gh: Greenhouse, n: int, dt: float) -> FluxTerm | SensorTerm:
        """The term for ``model`` (base terms only are wrapped or scaled)."""
        amp, tau = self.parameters(n)
        unit = model.capacity(gh) / physical_capacity(gh)
        if self.name == "solar_gain_change":
            return SolarGainChange(solar_term(model), amp, tau)
        if self.name == "extra_ventilation":
            return ExtraVentilation(model.capacity(gh), amp, tau)
        if self.name in ("heat_source", "night_heat_source"):
            return HeatSource(unit, amp, tau, night_only=self.name == "night_heat_source")
        if self.name == "thermal_mass":
            return CapacityChange(model.terms, amp, tau)
        if self.name == "sensor_radiation_bias":
            return RadiationBias(amp, tau)
        if self.name == "sensor_drift":
            return Drift(dt, amp, tau)
        raise ValueError(f"no term for effect {self.name!r}")


def solar_term(model: Model) -> FluxTerm:
    """The model's solar-gain term: the first term reading i_glob with no state coefficient."""
    for term in model.terms:
        if term.name in ("q_solar", "q_sol"):
            return term
    raise ValueError(f"model {model.name} has no solar gain term (q_solar or q_sol)")


def _pct(word_up: str, word_down: str) -> Callable[[float], str]:
    return lambda a: f"{word_up if a >= 0 else word_down} {abs(a) * 100:.0f} %"


LIBRARY: tuple[Effect, ...] = (
    Effect("solar_gain_change", "flux",
           "step change of the solar gain coefficient (cover transmission change: whitening, "
           "shading, second cover, dust)",
           "daytime residual proportional to radiation, from a date on",
           "d_solar", "-", -0.9, 1.5, 0.0, _pct("solar gain rose", "solar gain fell")),
    Effect("extra_ventilation", "flux",
           "added air exchange (door left open, torn cover, extra leakage)",
           "residual proportional to T_in - T_out (pulls towards outside), from a date on",
           "n_extra", "h-1", 0.0, 60.0, 0.0, lambda a: f"{a:.2g} extra air changes per hour"),
    Effect("heat_source", "flux",
           "undeclared constant heat input (heater, warm pipe, machine)",
           "warm offset at all hours, largest relative effect at night, from a date on",
           "p_heat", "W m-2", 0.0, 400.0, 0.0, lambda a: f"{a:.3g} W m-2 of heat added"),
    Effect("night_heat_source", "flux",
           "undeclared heat input at night only (night heater, night screen heating)",
           "warm offset at night only, from a date on",
           "p_night_heat", "W m-2", 0.0, 400.0, 0.0,
           lambda a: f"{a:.3g} W m-2 of heat added at night"),
    Effect("thermal_mass", "capacity",
           "change of the heat capacity coupled to the air (water barrels, concrete, more crop)",
           "damped, lagging daily swing: residual opposite to dT/dt, from a date on",
           "m_capacity", "-", 0.25, 8.0, 1.0, lambda a: f"heat capacity x {a:.2f}"),
    Effect("sensor_radiation_bias", "sensor",
           "inside sensor heated by the sun (missing or poor radiation shield)",
           "reading too warm in proportion to radiation, no lag, from a date on",
           "k_rad", "K W-1 m2", 0.0, 0.03, 0.0,
           lambda a: f"sensor reads {a * 1000:.2f} mK per W m-2 too warm"),
    Effect("sensor_drift", "sensor",
           "drifting inside temperature sensor (ageing, contamination)",
           "residual growing linearly with time from a date on",
           "a_drift", "K d-1", -3.0, 3.0, 0.0, lambda a: f"sensor drifts {a:+.3g} K per day"),
)
EFFECTS = {e.name: e for e in LIBRARY}

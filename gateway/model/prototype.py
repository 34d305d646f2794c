"""The four-parameter grey-box model of the low-cost kit's prototype (thesis §III.2.2).

    rho_a V/S_f dT_in/dt = Q_solar - Q_cnv_cnd - Q_loss - Q_thermal        (III.14)

The lumped parameters already carry 1/C_a (III.16, III.18, III.22), so the "capacity" here is
rho_a V/S_f [kg m-2] and each flux is in W m-2 divided by C_a [J kg-1 K-1], i.e. K kg m-2 s-1.
Inputs: outside temperature, wind, outside global radiation (and inside RH through the data).
Search box: §III.4.2.1.2.A; defaults: the RIWPSO values of table 6 (Biskra prototype).
"""

from __future__ import annotations

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model.heating_control import HeatingControl
from gateway.model.model import Model
from gateway.model.terms import ALWAYS, SUNLIT, FluxTerm, Index, Parameter, const, row_values
from gateway.model.vent_control import ControlledVentilation

# Variation ratios for online use: the thesis gives none for this model (table 12 is for the
# Almería model); 10 % follows its "fast" class for convective and loss coefficients.
_R_FAST = 0.10
# h_i = 5.2 |T_in - T_out|^0.33 [W m-2 K-1] (III.10), as 0-d operands (terms.const)
_H_I_COEF, _H_I_EXP = const(5.2), const(0.33)


class SolarGain(FluxTerm):
    linear_in_parameters = True
    state_dependent = False
    name = "q_solar"
    equation = "III.15"
    description = "short-wave radiation absorbed inside: C_solar I"
    requires = ("i_glob",)
    parameters = (
        Parameter("c_solar", "kg K J-1 (alpha_c tau_c / C_a)", 0.0, 2e-4,
                  6.834498e-5, 0.02, SUNLIT, "solar gain coefficient alpha_c tau_c / C_a"),
    )

    def coefficients(self, p, x, t_in, t: Index):
        return p["c_solar"] * x["i_glob"][t], 0.0


class CoverConvection(FluxTerm):
    linear_in_parameters = True
    name = "q_cnv_cnd"
    equation = "III.17"
    description = "convection and conduction through the cover: -C_cnv_cnd U (T_in - T_out)"
    requires = ("t_out", "wind")
    parameters = (
        Parameter("c_cnv_cnd", "kg K J-1 (1/C_a)", 0.0, 2e-3, 4.142013e-4, _R_FAST, ALWAYS,
                  "cover convection-conduction coefficient 1/C_a"),
    )

    @staticmethod
    def _h_i(t_in, t_out):
        """h_i [W m-2 K-1] (III.10)."""
        return _H_I_COEF * np.abs(t_in - t_out) ** _H_I_EXP

    @classmethod
    def _h(cls, h_o, t_out, t_in):
        """(h_i, U) [W m-2 K-1] for h_o (III.9), T_out and T_in."""
        h_i = cls._h_i(t_in, t_out)
        return h_i, h_o * h_i / (h_o + h_i)  # U = (1/h_o + 1/h_i)^-1, safe when h_i = 0

    def coefficients(self, p, x, t_in, t: Index):
        t_out = x["t_out"][t]  # read once: the free runs call this at every step
        s = p["c_cnv_cnd"] * self._h(x["h_o"][t], t_out, t_in)[1]
        return s * t_out, s

    def linearised(self, p, x, t_in, t: Index):
        return self._linearised(p["c_cnv_cnd"], x["h_o"][t], x["t_out"][t], t_in)

    @classmethod
    def _linearised(cls, c, h_o, t_out, t_in):
        """(g, s, k) with the slope k = -∂Q/∂T_in = C U (1 + 0.33 h_o / (h_o + h_i)): h_i grows
        with |T_in - T_out| (III.10), so the loss grows faster than C U; finite at h_i = 0."""
        h_i = cls._h_i(t_in, t_out)
        share = h_o / (h_o + h_i)
        s = c * (h_i * share)  # U = h_o h_i / (h_o + h_i)
        return s * t_out, s, s + _H_I_EXP * (s * share)

    def bind(self, p, x, rows: slice):
        """h_o and T_out as 0-d operands for the rows (``FluxTerm.bind``, ``terms.const``)."""
        h_o, t_out = row_values(x["h_o"], rows), row_values(x["t_out"], rows)
        c, a, linearised = p["c_cnv_cnd"], rows.start, self._linearised
        return lambda t_in, t: linearised(c, h_o[t - a], t_out[t - a], t_in)


class AirLeakage(FluxTerm):
    linear_in_parameters = True
    state_dependent = False
    name = "q_loss"
    equation = "III.19"
    description = "air exchange losses: -C_loss rho_a (T_in - T_out)"
    requires = ("t_out",)

    parameters = (
        Parameter("c_loss", "m s-1 (ACH V / (3600 S_f))", 0.0, 2e-3, 2.556947e-4, _R_FAST,
                  ALWAYS, "leakage air flow per floor area (III.20 prints ACH/3600 [s-1])"),
    )

    def __init__(self, rho: float = 1.205) -> None:
        self.rho = rho  # gamma_0 [kg m-3], table 2

    def coefficients(self, p, x, t_in, t: Index):
        s = p["c_loss"] * self.rho
        return s * x["t_out"][t], s


class SkyRadiation(FluxTerm):
    linear_in_parameters = True
    state_dependent = False
    name = "q_thermal"
    equation = "III.21"
    description = "long-wave loss to the sky: -C_thermal h_o (T_in - T_sky)"
    requires = ("t_out", "wind")
    optional = ("rh_out",)  # T_sky's clear-sky emissivity (gateway/model/sky.py)
    parameters = (
        Parameter("c_thermal", "kg K J-1 ((1 - tau_c)/C_a)", 0.0, 2e-4, 2.556266e-5, _R_FAST,
                  ALWAYS, "thermal loss coefficient (1 - tau_c)/C_a"),
    )

    def coefficients(self, p, x, t_in, t: Index):
        s = p["c_thermal"] * x["h_o"][t]
        return s * x["t_sky"][t], s


def leakage_flow(c_loss, gh: Greenhouse):
    """The leakage's air flow G [m3 s-1] = C_loss S_f: III.14 divides the balance by S_f, so
    C_loss [m s-1] is a flow per floor area (docs/model.md, "Units")."""
    return c_loss * gh.floor_area


def prototype_capacity(gh: Greenhouse) -> float:
    """rho_a V / S_f [kg m-2] (III.14)."""
    return gh.air_density * gh.volume / gh.floor_area


def build_prototype(gh: Greenhouse | None = None, vent_control: bool = False,
                    heating: bool = False) -> Model:
    """The four-term model of III.14–III.22 (table 2 constants from ``gh``); ``vent_control``
    adds the air exchange of controller-moved vents (gateway/model/vent_control.py, two more
    parameters; ``--model prototype+vent_control``, the shipped gateway.toml's model since issue
    10 item 3: docs/effects.md, forecasts); ``heating`` (with ``vent_control``) the heat of a
    thermostat-run heater (gateway/model/heating_control.py; ``prototype+vent_control+heating``)."""
    if heating and not vent_control:
        raise ValueError("the heated prototype is the vented one plus the heater")
    rho = 1.205 if gh is None else gh.air_density
    terms: tuple[FluxTerm, ...] = (SolarGain(), CoverConvection(), AirLeakage(rho), SkyRadiation())
    if vent_control:
        terms += (ControlledVentilation(rho),)
    if heating:
        terms += (HeatingControl(),)
    name = "prototype" + "+vent_control" * vent_control + "+heating" * heating
    return Model(
        name=name,
        terms=terms,
        capacity=prototype_capacity,
        description="four-parameter grey-box model of the low-cost kit (III.14–III.22)"
        + (" with controller-moved vents" if vent_control else "")
        + (" and a thermostat-run heater" if heating else ""),
        capacity_equation="III.14",
    )

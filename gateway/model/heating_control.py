"""Heat of a heating system a thermostat runs, which the kit does not see (issue 10, heated houses).

Most glasshouses are heated: a climate computer drives the pipe or air heater from how far the
air is below a heating setpoint (a P band, Bot 1983, *Greenhouse climate: from physical
processes to a dynamic model*, §7; Vanthoor 2011, §2.4, where the heating rises over a band
below the setpoint). The kit reads the air only, so without this term the prototype's losses
must be re-estimated, one step behind, to hold the air up on a cold night, and a forecast then
lets the air fall that the heater holds. This term makes the heat a function of the state the
forecast itself predicts, the vent controller's counterpart (gateway/model/vent_control.py):

    Q_hc = C_hc σ(T_hs − T_in)            σ(z) = w ln(1 + e^{z / w}),  w = ``SMOOTH_K``

σ the same smooth max(0, z) [K] as the vents' (vent_control.soft_excess), C_hc [kg m-2 s-1] the
heater's gain per kelvin below the setpoint and T_hs [°C] the heating setpoint; in the
prototype's lumped units (III.14: fluxes divided by C_a, K kg m-2 s-1; C_hc = 0.06 is about
60 W m-2 K-1). No upper limit on the heat: a heater at full power shows as a lower gain. Both
parameters are re-estimated at every step (a thermostat acts day and night). The flux does not
depend on the state through (g, s) (s = 0), but its exact slope for the exponential step does:

    k = −∂Q_hc/∂T_in = C_hc σ'(T_hs − T_in),   σ'(z) = 1 / (1 + e^{−z/w}).
"""

from __future__ import annotations

from gateway.model.terms import ALWAYS, FluxTerm, Index, Parameter
from gateway.model.vent_control import soft_excess, soft_step


class HeatingControl(FluxTerm):
    """Heat a thermostat gives below a setpoint: C_hc σ(T_hs − T_in)."""

    name = "q_heating_control"
    equation = "III.14 heat source, σ a smooth max(0, T_hs − T_in)"
    description = "heat of a heater a thermostat runs below T_hs (unseen by the kit)"
    requires = ()
    parameters = (
        Parameter("c_hc", "kg m-2 s-1 (W m-2 K-1 / C_a: heat per K below T_hs)", 0.0, 0.2, 0.01,
                  0.10, ALWAYS, "heater gain per kelvin below the heating setpoint"),
        Parameter("t_hs", "°C", 0.0, 25.0, 10.0, 0.02, ALWAYS, "the thermostat's heating setpoint"),
    )

    def coefficients(self, p, x, t_in, t: Index):
        return p["c_hc"] * soft_excess(p["t_hs"] - t_in), 0.0

    def linearised(self, p, x, t_in, t: Index):
        """Also the exact slope k (module docstring): the heat falls as the air warms."""
        z = p["t_hs"] - t_in
        c = p["c_hc"]
        return c * soft_excess(z), 0.0, c * soft_step(z)

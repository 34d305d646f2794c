"""Leakage air exchange that grows with the wind (issue 10: the base on houses we did not build).

The prototype's leakage C_loss (III.19) is a constant exchange. A real cover leaks more when it
blows: the infiltration rate of a closed greenhouse is, to first order, a + b·u (Boulard &
Draoui 1995, *Natural ventilation of a greenhouse with continuous roof vents*, J. Agric. Eng.
Res. 61; Baptista et al. 1999, *Air exchange rates of closed greenhouses*, Acta Hort. 507),
and GreenLight / Vanthoor 2011 (*A model-based greenhouse design method*, eq. 2.53) writes the
leakage as f_leak = c_leakage max(u, 0.25). With the constant alone, a fit of a calm week and a
windy one cannot both hold (on bleiswijk-10-29, C_loss went to 0 in one window and to its
upper bound in another; docs/effects.md, "Base structure"). This term is the b·u part, the
prototype's C_loss staying as the a part (the exchange at zero wind):

    Q_wl = −C_wl ρ_a u (T_in − T_out)                                       (III.19 form)

u [m s-1] the measured wind, C_wl [-] so that C_wl u is in the units of C_loss [m s-1]; in the
prototype's lumped units (III.14: fluxes divided by C_a), as ``AirLeakage``. As there, the
rate the air of a house of mean height V/S_f sees is C_wl u S_f / V: C_loss and C_wl u are the
exchanged flow per unit floor area [m3 m-2 s-1], the thesis's "s-1" holding for V/S_f ≈ 1 m
(its prototype box). In those terms C_wl is GreenLight's c_leakage (1e-4 for a Venlo
glasshouse); the two-node test generator's kit box (0.9 air changes per hour per m s-1, 1.12 m
high) is 2.8e-4, its 3.5 m house (0.25 h-1 per m s-1) 2.4e-4, and 0.5 h-1 per m s-1 in a
3.5 m house 4.9e-4. Bounds: 0 .. ``C_WL_MAX`` = 5e-4, which at 4 m s-1 equals the
prototype's C_loss bound (2e-3 m s-1). Variation ratio 10 %, the prototype's "fast" class for
loss coefficients; active always (the wind blows day and night).

The coefficients do not depend on the state (s = C_wl ρ_a u, g = s T_out): the exponential
step's slope is s and needs no override; the term is linear in C_wl.
"""

from __future__ import annotations

from gateway.model.terms import ALWAYS, FluxTerm, Index, Parameter

C_WL_MAX = 5e-4
"""[-] upper bound of C_wl (module docstring)."""


class WindLeakage(FluxTerm):
    """Leakage proportional to the wind: −C_wl ρ_a u (T_in − T_out)."""

    linear_in_parameters = True
    state_dependent = False
    name = "q_wind_leakage"
    equation = "III.19 form, rate C_wl u"
    description = "leakage air exchange growing with the wind: -C_wl rho_a u (T_in - T_out)"
    requires = ("t_out", "wind")
    parameters = (
        Parameter("c_wl", "- (leakage flow per floor area per m s-1 of wind)", 0.0, C_WL_MAX, 5e-5,
                  0.10, ALWAYS, "leakage per unit wind speed"),
    )

    def __init__(self, rho: float = 1.205) -> None:
        self.rho = rho  # gamma_0 [kg m-3], table 2

    def coefficients(self, p, x, t_in, t: Index):
        s = p["c_wl"] * self.rho * x["wind"][t]
        return s * x["t_out"][t], s

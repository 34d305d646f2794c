"""The crop's transpiration as an optional part of the diagnosis's base (docs/effects.md, "Base
structure"; rule lt).

The prototype (III.14) has no crop; the houses it is used on have one, and a transpiring crop
turns a large share of the absorbed sun into latent heat. Stanghellini's big-leaf balance (1987)
and the Almería model's Baille form (III.28–III.29, gateway/model/almeria.py ``Transpiration``)
split it into a radiative part, ``C_A I``, and an aerodynamic part driven by the air's vapour
pressure deficit, ``C_B LAI VPD``. The radiative part is linear in I_glob, which the prototype's
``c_solar`` already carries; the aerodynamic part is not, and it grows with the air's own
temperature, a loss that steadies a warm, dry house the way more air exchange would. So only
that part is added, lumped:

    Q_lat = −c_vpd VPD,  VPD = max(p_ws(T_in) − p_w,in, 0)  [kPa]                (III.29 form)

with T_in the simulated air and p_w,in the measured inside vapour pressure (III.4; behind an
electronic sensor offset, from the corrected temperature: recomputed.py), as the Almería term
reads them, so a free run does not read the measured temperature.
"""

from __future__ import annotations

import numpy as np

from gateway.model import psychrometrics as psy
from gateway.model.terms import ALWAYS, FluxTerm, Index, Parameter

C_VPD = Parameter("c_vpd", "W m-2 kPa-1", 0.0, 100.0, 0.0, None, ALWAYS,
                  "aerodynamic transpiration per vapour pressure deficit, lumped C_B LAI (III.29)")
"""Upper bound: Penman–Monteith's 2 LAI ρ c_p / (r_b (Δ + γ*)) for LAI 3, r_b 200 s m-1 and
Δ + γ* ≈ 0.4 kPa K-1 is ~90 W m-2 kPa-1; the Almería model's C_B LAI reaches 26 × LAI."""


class CropLatent(FluxTerm):
    """``Q = −c_vpd max(p_ws(T_in) − p_w,in, 0)`` [W m-2] in the model's own units (``unit``:
    structure.model_unit). Returned as the tangent at the step's state, (g, s) with
    s = c_vpd dp_ws/dT, so the exponential step relaxes with the loss's own slope."""

    name = "q_lat"
    equation = "III.29 form"
    description = "crop transpiration's vapour-deficit loss: -c_vpd VPD(T_in, p_w,in)"
    requires = ("rh_in",)
    parameters = (C_VPD,)

    def __init__(self, unit: float, reference: str = "inside") -> None:
        self.unit = unit
        self.reference = reference
        """"inside": the deficit against the measured inside vapour pressure (as III.29);
        "outside": against the outside air's (a study variant: the inside reading's vapour
        pressure carries the measured air temperature, the outside's does not)."""

    def _p_w(self, x, t: Index) -> np.ndarray:
        if self.reference == "inside":
            return x["p_w_in"][t]
        return psy.vapour_pressure(x["t_out"][t], x["rh_out"][t])

    def coefficients(self, p, x, t_in, t: Index):
        p_ws, slope = psy.saturation_vapour_pressure_and_slope(t_in)
        vpd = p_ws - self._p_w(x, t)
        c = self.unit * p["c_vpd"]
        dry = vpd > 0.0
        s = np.where(dry, c * slope, 0.0)
        # Q(T) = −c VPD(T_in) at the state, with slope −s: g = Q + s T_in
        return np.where(dry, s * t_in - c * vpd, 0.0), s

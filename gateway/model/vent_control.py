"""Air exchange of vents moved by a climate controller the kit does not see (issue 10).

A greenhouse's climate computer opens its vents in proportion to how far the air is above a
ventilation setpoint (a P controller on T_in, the usual "temperature-driven venting": Bot 1983,
*Greenhouse climate: from physical processes to a dynamic model*, §7; Vanthoor 2011, *A
model-based greenhouse design method*, §2.4, where the vent opening rises linearly over a band
above the setpoint). The kit reads no vent position, so the prototype's leakage C_loss (III.19)
must follow every controller move by adapting, one step behind, and a forecast holds it at the
start's value while the air it forecasts warms. This term makes the added exchange a function
of the state the forecast itself predicts:

    Q_vc = −C_vc ρ_a δ_sun σ(T_in − T_vc) (T_in − T_out)                 (III.19 form)
    σ(z) = w ln(1 + e^{z / w}),   w = ``SMOOTH_K``,   δ_sun = [I_glob > 5 W m-2]

σ is a smooth max(0, z) [K] (the band's lower edge rounded over ``w``, so the flux and its slope
are continuous in the state for the exponential step), C_vc [m s-1 K-1] the exchanged flow per
floor area per kelvin above the setpoint (÷ V/S_f: air changes per second) and T_vc [°C] the
day's ventilation setpoint; in the prototype's lumped units (III.14: fluxes divided by C_a), as
``AirLeakage``. Both are estimated online with the others while the sun is up (``SUNLIT``,
§IV.2.1.2's activity rule), and the term acts only then (δ_sun): a controller vents the sun's
heat by day on a day setpoint, and at night, where neither parameter is seen, the night's
exchange is the leakage's. (Acting at night with the day's setpoint, the first trial,
over-cooled every summer night: the setpoint the day's fit settles on, 16-20 °C, is below a
summer night's air; docs/effects.md.) The exact slope for the exponential step is

    k = −∂Q_vc/∂T_in = C_vc ρ_a δ_sun [σ(z) + σ'(z) (T_in − T_out)],   σ'(z) = 1 / (1 + e^{−z/w}).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gateway.model.terms import (
    SUN_THRESHOLD,
    SUNLIT,
    FluxTerm,
    Index,
    Parameter,
    const,
    row_columns,
    row_values,
)

SMOOTH_K = 0.5
"""[K] width w over which σ rounds the setpoint's corner."""
_ZERO, _HALF, _ONE = const(0.0), const(0.5), const(1.0)  # 0-d operands (terms.const)
_W = const(SMOOTH_K)  # w as a 0-d operand, built once (the hot path: a free run's every step)


def _width(w: float) -> np.ndarray:
    return _W if w == SMOOTH_K else const(w)


def soft_excess(z: np.ndarray, w: float = SMOOTH_K) -> np.ndarray:
    """σ(z) = w ln(1 + e^{z/w}) [K]: ≈ max(0, z) beyond a few w, w ln 2 at z = 0 (NaN, a
    missing reading, stays NaN)."""
    z, w_ = np.asarray(z, dtype=float), _width(w)
    return np.maximum(z, _ZERO) + w_ * np.log1p(np.exp(-np.abs(z) / w_))  # = w ln(1 + e^{z/w})


def soft_step(z: np.ndarray, w: float = SMOOTH_K) -> np.ndarray:
    """σ'(z) = 1 / (1 + e^{−z/w}) [-]: the logistic, the derivative of ``soft_excess``."""
    return _HALF * (_ONE + np.tanh(_HALF * np.asarray(z, dtype=float) / _width(w)))


class ControlledVentilation(FluxTerm):
    """Vent air exchange rising above a day setpoint: −C_vc ρ_a δ_sun σ(T_in − T_vc) (T_in − T_out)."""

    name = "q_vent_control"
    equation = "III.19 form, σ a smooth max(0, T_in − T_vc)"
    description = "air exchange of vents a controller opens above T_vc (unseen by the kit)"
    requires = ("t_out", "i_glob")
    parameters = (
        Parameter("c_vc", "m s-1 K-1 (flow per floor area per K above T_vc)", 0.0, 1e-3, 1e-4,
                  0.10, SUNLIT, "controlled vent exchange per kelvin above the setpoint"),
        Parameter("t_vc", "°C", 15.0, 35.0, 25.0, 0.02, SUNLIT,
                  "the controller's ventilation setpoint"),
    )

    def __init__(self, rho: float = 1.205, c_vc_max: float | None = None) -> None:
        self.rho = rho  # gamma_0 [kg m-3], table 2
        if c_vc_max is not None:  # another box for C_vc (the diagnosis's WIDE_VENT_BOX)
            c_vc, t_vc = type(self).parameters
            self.parameters = (replace(c_vc, upper=c_vc_max), t_vc)

    derives = ("_q_vent_control.sun",)

    def derive(self, x) -> dict[str, np.ndarray]:
        """ρ_a δ_sun over the series (``Model.prepare`` adds it once)."""
        return {"_q_vent_control.sun": self.rho * (np.asarray(x["i_glob"]) > SUN_THRESHOLD)}

    def _gain(self, p, x, t: Index) -> np.ndarray | None:
        """C_vc ρ_a δ_sun [kg m-2 s-1 K-1]; None when no sample at ``t`` is sunlit (the flux is
        then 0 and the state's functions need not be evaluated: the night's steps cost nothing)."""
        sun = self._sun(x, t)
        return p["c_vc"] * sun if sun.any() else None

    def _sun(self, x, t: Index) -> np.ndarray:
        """ρ_a δ_sun [kg m-3] at ``t``: from ``Model.prepare``'s column when there."""
        sun = self.derived(x, "_q_vent_control.sun", t)
        return self.rho * (np.asarray(x["i_glob"][t]) > SUN_THRESHOLD) if sun is None else sun

    def coefficients(self, p, x, t_in, t: Index):
        c = self._gain(p, x, t)
        if c is None:
            return 0.0, 0.0
        s = c * soft_excess(t_in - p["t_vc"])
        return s * x["t_out"][t], s

    def linearised(self, p, x, t_in, t: Index):
        """Also the exact slope k (module docstring): the exchange grows with T_in."""
        c = self._gain(p, x, t)
        if c is None:
            return 0.0, 0.0, 0.0
        return self._linearised(c, p, x["t_out"][t], t_in)

    @staticmethod
    def _linearised(c, p, t_out, t_in):
        """(g, s, k) for the gain c = C_vc ρ_a δ_sun (``_gain``)."""
        z = t_in - p["t_vc"]
        s = c * soft_excess(z)
        return s * t_out, s, s + c * soft_step(z) * (t_in - t_out)

    def bind(self, p, x, rows: slice):
        """The gain once for the rows (``FluxTerm.bind``); rows without sun give 0."""
        sun = self._sun(x, rows)
        gain = row_columns(p["c_vc"] * sun, rows.stop - rows.start)
        lit, t_out = sun != 0.0, row_values(x["t_out"], rows)
        a, linearised = rows.start, self._linearised

        def at(t_in: np.ndarray, t: int) -> tuple:
            if not lit[t - a]:
                return 0.0, 0.0, 0.0
            return linearised(gain[t - a], p, t_out[t - a], t_in)

        return at

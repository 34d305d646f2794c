"""The pseudo-physical model of the Almería greenhouse (thesis §III.2.3, III.23–III.35).

    C_ter dT_in/dt = Q_sol + Q_cnv_ss - Q_cnd_cnv - Q_trp - Q_vent          (III.23)
    C_ter = c_p rho V / A                                                   (III.24)

Ten parameters with the hard bounds of table 13 and the variation ratios of table 12, except
the ventilation coefficients, which follow the standard Kittas/Boulard convention
(docs/model-notes.md §3): the discharge coefficient C_d is dimensionless around 0.6–0.8 rather than the
thesis's 15–35e-4, and the wind coefficient C_w is the usual pressure coefficient.
Defaults: the offline-calibrated values of table 8 (ventilation: literature values).
"""

from __future__ import annotations

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import psychrometrics as psy
from gateway.model.model import Model, OnlineGroup, RadiationSubmodel
from gateway.model.terms import (
    ALWAYS,
    CROP_DAY,
    CROP_NIGHT,
    SUNLIT,
    VENTS_OPEN,
    FluxTerm,
    Index,
    Parameter,
    const,
    row_columns,
    row_values,
)

C_TSW = Parameter("c_tsw", "-", 0.1, 1.0, 0.56, None, SUNLIT, "cover solar transmission")
_ZERO, _TINY = const(0.0), const(1e-300)  # 0-d operands of the per-step arithmetic (terms.const)


class AirSolarAbsorption(FluxTerm):
    linear_in_parameters = True
    state_dependent = False
    name = "q_sol"
    equation = "III.25, III.35"
    description = "short-wave radiation absorbed by the air: C_asw C_tsw I_out"
    requires = ("i_glob",)
    uses = ("c_tsw",)
    parameters = (
        Parameter("c_asw", "-", 0.1, 0.9, 0.42, 0.02, SUNLIT, "air short-wave absorption"),
    )

    def coefficients(self, p, x, t_in, t: Index):
        return p["c_asw"] * p["c_tsw"] * x["i_glob"][t], 0.0


class SoilConvection(FluxTerm):
    linear_in_parameters = True
    state_dependent = False
    name = "q_cnv_ss"
    equation = "III.26"
    description = "convection from the soil surface: C_cnv_ss (T_ss - T_in)"
    requires = ("t_soil",)
    parameters = (
        Parameter("c_cnv_ss", "W m-2 K-1", 1.0, 100.0, 13.43, 0.10, ALWAYS,
                  "soil surface–air convection coefficient"),
    )

    def coefficients(self, p, x, t_in, t: Index):
        s = p["c_cnv_ss"]
        return s * x["t_soil"][t], s


class CoverExchange(FluxTerm):
    linear_in_parameters = True
    state_dependent = False
    name = "q_cnd_cnv"
    equation = "III.27"
    description = "convection and conduction through the cover: -C_cnd_cnv (T_in - T_out)"
    requires = ("t_out",)
    parameters = (
        Parameter("c_cnd_cnv", "W m-2 K-1", 1.0, 300.0, 10.32, 0.10, ALWAYS,
                  "inside–outside convection-conduction coefficient"),
    )

    def coefficients(self, p, x, t_in, t: Index):
        s = p["c_cnd_cnv"]
        return s * x["t_out"][t], s


class Transpiration(FluxTerm):
    """Latent heat of crop transpiration (III.28–III.29, Baille et al. form).

    The printed III.29 mixes mass and energy units; this is the dimensionally consistent form
    of docs/model-notes.md §3: ``Q_trp = C_A (1 - exp(-k LAI)) I_in + C_B LAI VPD`` [W m-2] with C_B in
    W m-2 kPa-1 (C_Bd by day, C_Bn by night). VPD uses the simulated air temperature and the
    measured vapour pressure, so a free run does not read the measured temperature.
    """

    linear_in_parameters = True
    name = "q_trp"
    equation = "III.28–III.29"
    description = "crop transpiration: -(C_A (1 - e^-k LAI) I_in + C_B LAI VPD)"
    requires = ("i_glob", "rh_in")
    optional = ("lai",)  # else the greenhouse's [crop] lai
    uses = ("c_tsw",)
    parameters = (
        Parameter("c_a", "-", 0.2, 0.7, 0.26, 0.002, CROP_DAY, "radiative transpiration"),
        Parameter("c_bd", "W m-2 kPa-1", 4.0, 26.0, 8.27, 0.002, CROP_DAY,
                  "aerodynamic transpiration, day"),
        Parameter("c_bn", "W m-2 kPa-1", 4.0, 26.0, 10.28, 0.002, CROP_NIGHT,
                  "aerodynamic transpiration, night"),
    )

    derives = ("_q_trp.cover",)

    def __init__(self, extinction: float = 0.64) -> None:
        self.extinction = extinction

    def _cover(self, lai):
        """1 - e^(-k LAI) [-]: the share of the inside radiation the crop intercepts (III.29)."""
        return 1.0 - np.exp(-self.extinction * lai)

    def derive(self, x) -> dict[str, np.ndarray]:
        return {"_q_trp.cover": self._cover(x["lai"])}

    def _parts(self, p, x, t: Index) -> tuple[np.ndarray, np.ndarray]:
        """What does not read the state: the radiative flux C_A (1 - e^-k LAI) I_in [W m-2]
        and C_B LAI [W m-2 kPa-1] (C_Bd by day, C_Bn by night) at ``t``."""
        lai = x["lai"][t]
        i_out = x["i_glob"][t]
        i_in = p["c_tsw"] * i_out
        cover = self.derived(x, "_q_trp.cover", t)
        if cover is None:
            cover = self._cover(lai)
        b_lai = np.where(i_out > 5.0, p["c_bd"], p["c_bn"]) * lai
        return p["c_a"] * cover * i_in, b_lai

    @staticmethod
    def _latent(radiative, b_lai, p_ws, p_w_in):
        """The latent flux q = C_A (1 - e^-k LAI) I_in + C_B LAI VPD [W m-2] (III.29) for
        p_ws(T_in) and the measured p_w [kPa]."""
        return radiative + b_lai * np.maximum(p_ws - p_w_in, _ZERO)

    @classmethod
    def _linearised(cls, radiative, b_lai, p_w_in, t_in):
        """(g, s, k) from the parts (``_parts``): k = C_B LAI dp_ws/dT where the air is not
        saturated: a warmer air transpires more (the VPD grows with T_in)."""
        p_ws, slope = psy.saturation_vapour_pressure_and_slope(t_in)
        q = cls._latent(radiative, b_lai, p_ws, p_w_in)
        return -q, 0.0, np.where(p_ws > p_w_in, b_lai * slope, _ZERO)

    def coefficients(self, p, x, t_in, t: Index):
        q = self._latent(*self._parts(p, x, t), psy.saturation_vapour_pressure(t_in), x["p_w_in"][t])
        return -q, 0.0

    def linearised(self, p, x, t_in, t: Index):
        return self._linearised(*self._parts(p, x, t), x["p_w_in"][t], t_in)

    def bind(self, p, x, rows: slice):
        """The parts once for the rows (``FluxTerm.bind``)."""
        radiative, b_lai = (row_columns(v, rows.stop - rows.start) for v in self._parts(p, x, rows))
        p_w_in, a, linearised = row_values(x["p_w_in"], rows), rows.start, self._linearised
        return lambda t_in, t: linearised(radiative[t - a], b_lai[t - a], p_w_in[t - a], t_in)


class NaturalVentilation(FluxTerm):
    """Heat lost by natural ventilation and leakage (III.31–III.32, Kittas et al. 1997).

    ``G = C_d sqrt((A_r A_s / sqrt(A_r² + A_s²))² 2 g h ΔT/T_out + ((A_r + A_s)/2)² C_w u²)
    + G_leak`` [m3 s-1] (the standard form; printed III.31 has typos, docs/model-notes.md §3) and
    ``Q_vent = rho c_p G (T_in - T_out) / A`` [W m-2].
    """

    name = "q_vent"
    equation = "III.31–III.32"
    description = "natural ventilation and leakage: -rho c_p G (T_in - T_out) / A"
    requires = ("t_out", "wind")
    optional = ("vent_roof", "vent_side")  # else closed
    parameters: tuple[Parameter, ...] = (
        Parameter("c_ven_d", "-", 0.05, 1.0, 0.65, 0.07, VENTS_OPEN, "vent discharge coefficient"),
        Parameter("c_ven_w", "-", 0.01, 1.0, 0.09, 0.07, VENTS_OPEN, "wind pressure coefficient"),
        Parameter("c_loss", "m3 s-1", 0.1, 1.0, 0.2, 0.07, ALWAYS, "leakage air flow"),
    )

    derives = ("_q_vent.b", "_q_vent.w")

    def __init__(self, gh: Greenhouse) -> None:
        self.height = gh.vents.height_difference
        self.rho_cp_a = gh.air_density * psy.CP_AIR / gh.floor_area
        self._rho_cp_a = const(self.rho_cp_a)

    def derive(self, x) -> dict[str, np.ndarray]:
        return dict(zip(self.derives, self._buoyancy_wind(x, slice(None)), strict=True))

    def _drivers(self, x, t: Index) -> tuple[np.ndarray, np.ndarray]:
        """(B, W) at ``t``: from ``Model.prepare``'s columns when there, else computed."""
        b = self.derived(x, "_q_vent.b", t)
        return self._buoyancy_wind(x, t) if b is None else (b, x["_q_vent.w"][t])

    def _buoyancy_wind(self, x, t: Index) -> tuple[np.ndarray, np.ndarray]:
        """III.31's drivers B and W (:func:`kittas_drivers`) at ``t``: drivers only, so computed
        before any array of candidates."""
        return kittas_drivers(x["a_roof"][t], x["a_side"][t], self.height, x["t_out"][t],
                              x["wind"][t])

    @staticmethod
    def _still(b) -> bool:
        """True at one time step with B = 0 (roof or side vents shut: no buoyancy-driven
        exchange): B |T_in - T_out| is then 0 without reading the candidates' states."""
        return np.ndim(b) == 0 and b == 0.0

    def flow(self, p, x, t_in, t: Index) -> np.ndarray:
        """Ventilation flow G [m3 s-1] (III.31)."""
        b, w = self._drivers(x, t)
        buoyancy = 0.0 if self._still(b) else b * np.abs(t_in - x["t_out"][t])
        return p["c_ven_d"] * np.sqrt(buoyancy + p["c_ven_w"] * w) + p["c_loss"]

    def coefficients(self, p, x, t_in, t: Index):
        s = self.rho_cp_a * self.flow(p, x, t_in, t)
        return s * x["t_out"][t], s

    def linearised(self, p, x, t_in, t: Index):
        b, w = self._drivers(x, t)
        return self._linearised(b, p["c_ven_w"] * w, (0.5 * self.rho_cp_a) * p["c_ven_d"], p,
                                x["t_out"][t], t_in)

    def _linearised(self, b, c_w_w, half_d, p, t_out, t_in):
        """(g, s, k) with the slope k = rho c_p (G + dG/dT (T_in - T_out)) / A: the buoyancy flow
        grows with |T_in - T_out| (III.31), dG/dT (T_in - T_out) = C_d B |ΔT| / (2 sqrt(B |ΔT| +
        W)). ``c_w_w`` = C_w W and ``half_d`` = rho c_p C_d / (2 A) do not read the state."""
        still = self._still(b)
        buoyancy = 0.0 if still else b * np.abs(t_in - t_out)
        root = np.sqrt(buoyancy + c_w_w)
        s = self._rho_cp_a * (p["c_ven_d"] * root + p["c_loss"])
        if still:
            return s * t_out, s, s
        # root = 0 only where buoyancy = 0 (closed vents): the extra slope is 0 there
        extra = half_d * buoyancy / np.maximum(root, _TINY)
        return s * t_out, s, s + extra

    def bind(self, p, x, rows: slice):
        """C_w W and rho c_p C_d / (2 A) once for the rows (``FluxTerm.bind``)."""
        b, w = self._drivers(x, rows)
        c_w_w = row_columns(p["c_ven_w"] * w, rows.stop - rows.start)
        b_rows, t_out = row_values(b, slice(0, len(b))), row_values(x["t_out"], rows)
        half_d, a = (0.5 * self.rho_cp_a) * p["c_ven_d"], rows.start
        return lambda t_in, t: self._linearised(b_rows[t - a], c_w_w[t - a], half_d, p,
                                                t_out[t - a], t_in)


def kittas_drivers(a_roof, a_side, height: float, t_out, wind) -> tuple[np.ndarray, np.ndarray]:
    """The buoyancy coefficient B = A_eff² 2 g h / T_out [m6 s-2 K-1] (A_eff = A_r A_s /
    sqrt(A_r² + A_s²)) and the wind term W = ((A_r + A_s)/2)² u² [m6 s-2] of III.31, so that
    G = C_d sqrt(B |T_in − T_out| + C_w W) + G_leak. Areas [m2], height [m], T_out [°C],
    u [m s-1]."""
    a_r, a_s = np.asarray(a_roof, dtype=float), np.asarray(a_side, dtype=float)
    norm = np.sqrt(a_r * a_r + a_s * a_s)
    a_eff = np.where(norm > 0, a_r * a_s / np.where(norm > 0, norm, 1.0), 0.0)
    b = a_eff**2 * (2.0 * psy.GRAVITY * height) / (np.asarray(t_out) + psy.KELVIN)
    return b, ((a_r + a_s) / 2.0) ** 2 * np.asarray(wind) ** 2


def ventilation_driver(gh: Greenhouse, dt_in_out, t_out, wind) -> np.ndarray:
    """The ventilation driver D = sqrt(B |T_in − T_out| + C_w W) [m3 s-1] of III.31 through the
    house's fully open vents, with the published wind coefficient C_w (0.09): the flow per unit
    discharge coefficient, without leakage (G = C_d D + G_leak there). ΔT [K], T_out [°C],
    u [m s-1]. The virtual sensor's opening target is G / D (docs/vsensor.md, eighth pass)."""
    from gateway.model.drivers import roof_vent_area, side_vent_area

    full = np.array(100.0)
    b, w = kittas_drivers(roof_vent_area(gh.vents, full), side_vent_area(gh.vents, full),
                          gh.vents.height_difference, t_out, wind)
    c_w = next(p.default for p in NaturalVentilation.parameters if p.name == "c_ven_w")
    return np.sqrt(b * np.abs(np.asarray(dt_in_out, dtype=float)) + c_w * w)


def driver_constants(gh: Greenhouse, t_out_ref: float, floor_wind: float) -> tuple[float, float, float]:
    """(b, w, floor) of :func:`ventilation_driver` at T_out = ``t_out_ref`` [°C]: b = D² at 1 K
    and no wind [m6 s-2 K-1], w = D² at 1 m s-1 and ΔT 0 [m4], floor = D at ``floor_wind``
    [m s-1] and ΔT 0 [m3 s-1] (the virtual sensor's opening target: D = sqrt(b|ΔT| + w u²))."""
    d = [float(ventilation_driver(gh, dt, t_out_ref, u))
         for dt, u in ((1.0, 0.0), (0.0, 1.0), (0.0, floor_wind))]
    return d[0] ** 2, d[1] ** 2, d[2]


def almeria_capacity(gh: Greenhouse) -> float:
    """C_ter = c_p rho V / A [J m-2 K-1] (III.24)."""
    return psy.CP_AIR * gh.air_density * gh.volume / gh.floor_area


def build_almeria(gh: Greenhouse) -> Model:
    """The five-flux model of III.23 with the radiation sub-model III.35 (ten parameters)."""
    return Model(
        name="almeria",
        terms=(
            AirSolarAbsorption(),
            SoilConvection(),
            CoverExchange(),
            Transpiration(gh.crop.extinction),
            NaturalVentilation(gh),
        ),
        capacity=almeria_capacity,
        radiation=RadiationSubmodel(C_TSW),
        description="pseudo-physical model of the Almería greenhouse (III.23–III.35)",
        capacity_equation="III.24",
        # §IV.2.2.2: air temperature every minute on the last 3 samples; the radiation
        # sub-model every 20 minutes on the last 60.
        online=(OnlineGroup("t_in", (), 3, 1), OnlineGroup("i_in", ("c_tsw",), 60, 20)),
    )

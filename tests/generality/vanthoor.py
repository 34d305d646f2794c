"""Third generator of the generality suite: a reduced Vanthoor (2011) / GreenLight climate model
of a 4-ha Venlo glasshouse. HELD OUT: never used to tune the diagnosis or the forecasts.

Not product code, and not written from our model's equations: the physics follows

  [1] Vanthoor, B., Stanghellini, C., van Henten, E. J., de Visser, P. H. B. (2011). A
      methodology for model-based greenhouse design: Part 1, a greenhouse climate model for a
      broad range of designs and climates. Biosystems Engineering 110, 363-377
      (equation numbers below are [1]'s; parameter values from its Table 1 and the Dutch
      column of Table 2);
  [2] Katzin, D., van Mourik, S., Kempkes, F., van Henten, E. J. (2020). GreenLight - an open
      source model for greenhouses with supplemental lighting. Biosystems Engineering 194,
      61-81 (the 4-ha reference house, its climate-control rules);
  [3] Stanghellini, C. (1987). Transpiration of greenhouse crops. PhD thesis, Wageningen
      (the stomatal resistance model [1] Eqs. 46-50 are taken from).

States (12 heat nodes + vapour): canopy (Eq. 1), air (Eq. 2; one compartment: no thermal
screen, so [1]'s top compartment is merged with it), floor (Eq. 3), five soil layers (Eq. 4),
inner and outer cover (Eqs. 7-8), heating pipes (Eq. 9), a water node (the thermal-mass change)
and the air's vapour pressure (Eq. 10).

- Short wave: global radiation split 50/50 into PAR and NIR; a share eta_GlobAir absorbed by
  the construction heats the air (Eq. 35), the cover absorbs its own share (Eq. 36); the rest
  reaches the canopy (Eqs. 25-28, PAR with the floor reflection) and the floor (Eqs. 33-34);
  NIR by Beer's law through the canopy (Eqs. 30-32 without the multi-reflection network).
- Long wave (FIR): R_12 = A_1 eps_1 eps_2 F_12 sigma (T_1^4 - T_2^4) (Eq. 37, view factors
  of Table 3): canopy-cover, canopy-floor, floor-cover, pipes-canopy/floor/cover, and the outer
  cover to the sky. Glass is opaque to FIR (tau_RfFir = 0), so only the cover sees the sky.
- Sky: [1] takes the sky temperature as a measured input, not a formula of T_out: the window's
  measured sky temperature (Bleiswijk file; shifted with the air for the summer window).
- Convection and conduction (Table 4): canopy-air 2 alpha LAI; floor-air 1.7 |dT|^(1/3)
  (floor warmer) or 1.3 |dT|^(1/4); air-cover 1.86 |dT|^(1/3) A_Cov/A_Flr; cover-outside
  A_Cov/A_Flr (2.8 + 1.2 v); pipes-air 1.99 pi phi l |dT|^0.32; conduction through cover and
  soil layers.
- Ventilation: roof vents only (Venlo), Eq. 64
  f = U A_Roof C_d / (2 A_Flr) sqrt(|g h_Vent (T_Air - T_Out) / (2 T_mean) + C_w v^2|),
  plus leakage Eq. 70: f_leak = c_leakage max(v, 0.25); their sum, Eq. 71.
- Vapour (Eq. 10): transpiration by Stanghellini's big-leaf model (Eqs. 46-50: r_b = 275 s/m,
  r_s = r_s,min rf(R_Can) rf(CO2) rf(VP)), condensation on the cover (Eq. 42-43, smoothed
  switch), exchange with the outside air; latent heat taken from the canopy and given to the
  cover (Eq. 41); misting (fog) takes its latent heat from the air (Eq. 2's L_AirFog).
- Climate control, after [2]'s rules: roof vents on a proportional band above a temperature
  setpoint, humidity venting above 90 % RH, closed when the air is cold. No heating (unheated
  glasshouse) unless a change adds one.

Integration: every 30-s sub-step the conductances are frozen at the current state (FIR
linearised exactly as sigma (T1^2 + T2^2)(T1 + T2) (T1 - T2)) and the heat network is advanced
by backward Euler (unconditionally stable with the 790 J m-2 K-1 cover layers of Eq. 20); the
vapour balance is advanced implicitly first, and the latent heats follow from the mass fluxes
so applied. ``Run.energy_residual`` checks that the stored heat equals the fluxes applied.

Departures from [1], all documented: one air compartment; no CO2 state (rf(CO2) at 400 ppm);
constant LAI; the deep-soil boundary is the window's mean outside temperature + 3 K (not
Eq. 77's yearly sine: a 14-day window has no phase).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SIGMA = 5.67e-8  # Stefan-Boltzmann [W m-2 K-4]
KELVIN = 273.15
L_VAP = 2.45e6  # latent heat of evaporation [J kg-1] (Table 1)
GAMMA = 65.8  # psychrometric constant [Pa K-1] (Table 1)
M_WATER, R_GAS = 18.0, 8314.0  # [kg kmol-1], [J kmol-1 K-1] (Table 1)
RHO_AIR, CP_AIR, G = 1.2, 1e3, 9.81  # Eq. 23 at sea level; Table 1
CP_WATER = 4.18e3  # [J kg-1 K-1]
SUBSTEP = 30.0  # [s]


def saturation_vp(t: float) -> float:
    """Saturation vapour pressure [Pa] at t [°C] (Tetens, as in GreenLight's satVp)."""
    return 610.78 * np.exp(17.2694 * t / (t + 238.3))


@dataclass(frozen=True)
class Venlo:
    """A 4-ha Dutch Venlo glasshouse: [1] Tables 1-2 (NL) and [2]'s reference house."""

    floor_area: float = 4e4  # A_Flr [m2] ([2]: 4 ha)
    cover_ratio: float = 1.21  # A_Cov / A_Flr [-] ([2]: 4.84 ha of cover)
    height: float = 4.2  # h_Gh mean height [m] (Table 2)
    roof_ratio: float = 0.1  # A_Roof / A_Flr [-] (Table 2)
    h_vent: float = 0.68  # vertical size of a vent opening [m]
    c_d: float = 0.75  # discharge coefficient [-]
    c_w: float = 0.09  # wind pressure coefficient [-]
    c_leakage: float = 1e-4  # leakage coefficient [-] (Eq. 70)
    eta_glob_air: float = 0.1  # share of global radiation absorbed by the construction [-]
    tau_cover: float = 0.85  # PAR and NIR transmission of the glass roof [-]
    a_cover: float = 0.02  # PAR and NIR absorption of the roof: 1 - 0.85 - 0.13 [-]
    eps_cover: float = 0.85  # FIR emission of glass (1 - rho_RfFir 0.15, tau_RfFir 0)
    cap_cover: float = 0.906 * 4e-3 * 2.6e3 * 0.84e3  # cos(25°) h rho c_p (Eq. 18)
    k_cover: float = 1.05 / 4e-3  # conduction through the 4-mm glass [W m-2 K-1]
    lai: float = 3.0  # [m2 m-2] (Katzin's laiMax)
    cap_leaf: float = 1.2e3  # [J K-1 m-2 leaf]
    alpha_leaf: float = 5.0  # leaf-air convection [W m-2 K-1]
    rho_can_par: float = 0.07
    rho_can_nir: float = 0.35
    k_par: float = 0.7  # K1 = K2 (Table 1)
    k_nir: float = 0.27
    k_fir: float = 0.94
    rho_flr_par: float = 0.65
    rho_flr_nir: float = 0.5
    cap_floor: float = 0.02 * 2300.0 * 0.88e3  # h rho c_p of the 2-cm floor (Eq. 22)
    lambda_floor: float = 1.7
    h_floor: float = 0.02
    soil_layers: tuple[float, ...] = (0.04, 0.08, 0.16, 0.32, 0.64)  # [m]
    rho_c_soil: float = 1.73e6  # [J m-3 K-1]
    lambda_soil: float = 0.85  # [W m-1 K-1]
    h_soil_out: float = 1.28  # external soil layer [m]
    pipe_length: float = 1.875  # [m m-2]
    pipe_d_out: float = 51e-3
    pipe_d_in: float = 47e-3
    eps_pipe: float = 0.88
    r_b: float = 275.0  # boundary-layer resistance [s m-1]
    r_s_min: float = 82.0  # [s m-1]
    vent_setpoint: float = 22.0  # roof vents open above it [°C] ([2]: heating setpoint + dead zone)
    vent_band: float = 4.0  # [K]
    rh_max: float = 90.0  # humidity venting above it [%] ([2])
    rh_band: float = 5.0  # [%]
    vent_cold: float = 10.0  # humidity venting only above it (+ 4 K band) [°C]

    @property
    def cap_pipe(self) -> float:
        """Eq. 21 [J K-1 m-2]: steel wall + water inside."""
        steel = (self.pipe_d_out ** 2 - self.pipe_d_in ** 2) * 7850.0 * 640.0
        return 0.25 * np.pi * self.pipe_length * (steel + self.pipe_d_in ** 2 * 1e3 * CP_WATER)


@dataclass(frozen=True)
class Change:
    """An undeclared change from ``start`` (datetime64[s] UTC), kind and size:

    ``whitening`` (roof transmission x amount), ``leakage`` (c_leakage x amount), ``heater``
    (amount W m-2 into the pipes), ``night_heater`` (same while I_glob < 10 W m-2),
    ``thermal_mass`` (amount kg m-2 of water in open tanks, 3 W m-2 K-1 to the air),
    ``sun_sensor`` (sensor body heated by amount K per W m-2 above the canopy, 4-min lag, RH
    read at the body), ``drift`` (reading + amount K per day), ``misting`` (fog of amount
    kg m-2 s-1 from 10 to 16 h solar time, outside the library), ``controller`` (another vent
    controller: 18 °C, 2-K band, humidity venting from 80 % without the cold cut-off).
    """

    kind: str
    start: np.datetime64
    amount: float = 0.0


KINDS = ("whitening", "leakage", "heater", "night_heater", "thermal_mass", "sun_sensor", "drift",
         "misting", "controller")
N_SOIL = 5
CAN, AIR, FLR = 0, 1, 2
SO = tuple(range(3, 3 + N_SOIL))
CIN, CEX, PIPE, WATER = 8, 9, 10, 11
N_NODES = 12
EDGES = ((CAN, AIR), (AIR, FLR), (AIR, CIN), (CIN, CEX), (FLR, SO[0]), (SO[0], SO[1]),
         (SO[1], SO[2]), (SO[2], SO[3]), (SO[3], SO[4]), (CAN, CIN), (CAN, FLR), (FLR, CIN),
         (PIPE, AIR), (PIPE, CAN), (PIPE, FLR), (PIPE, CIN), (WATER, AIR))
INCIDENCE = np.zeros((len(EDGES), N_NODES))
for _e, (_i, _j) in enumerate(EDGES):
    INCIDENCE[_e, _i], INCIDENCE[_e, _j] = 1.0, -1.0


def _fir(a: float, eps1: float, eps2: float, f: float, t1: float, t2: float) -> float:
    """Conductance [W m-2 K-1] of the FIR exchange of Eq. 37, linearised exactly at (t1, t2)."""
    k1, k2 = t1 + KELVIN, t2 + KELVIN
    return a * eps1 * eps2 * f * SIGMA * (k1 * k1 + k2 * k2) * (k1 + k2)


@dataclass
class Run:
    """The simulated truth on the window's 60-s grid."""

    time: np.ndarray
    t_air: np.ndarray  # [°C]
    vp_air: np.ndarray  # [Pa]
    t_body: np.ndarray  # inside sensor body [°C]
    t_can: np.ndarray
    r_can: np.ndarray  # global radiation above the canopy [W m-2]
    vent: np.ndarray  # roof opening [0-1]
    energy_residual: float = 0.0  # max |stored - applied| [W m-2] over the run
    extra: dict = field(default_factory=dict)


class Glasshouse:
    """One simulation of a :class:`Venlo` house over a weather window (tests/generality)."""

    def __init__(self, house: Venlo, weather, change: Change | None = None) -> None:
        self.h, self.w, self.change = house, weather, change
        h = house
        self.cap = np.zeros(N_NODES)
        self.cap[[CAN, AIR, FLR, CIN, CEX, PIPE, WATER]] = (
            h.cap_leaf * h.lai, h.height * RHO_AIR * CP_AIR, h.cap_floor, 0.1 * h.cap_cover,
            0.1 * h.cap_cover, h.cap_pipe, 1e3)  # Eqs. 19-22; Eq. 20: 0.1 capCov per layer
        self.cap[list(SO)] = np.array(h.soil_layers) * h.rho_c_soil
        self.a_can = 1.0 - np.exp(-h.k_fir * h.lai)  # Table 3
        self.pipe_area = np.pi * h.pipe_length * h.pipe_d_out
        self.t_soil_out = float(np.mean(weather.t_out)) + 3.0
        sec = (weather.time - weather.time[0]).astype("timedelta64[s]").astype(float)
        self.seconds = sec
        on = np.zeros(len(sec), bool) if change is None else weather.time >= change.start
        self.on = on
        solar_hour = (sec / 3600.0 + weather.longitude / 15.0
                      + (weather.time[0] - weather.time[0].astype("datetime64[D]"))
                      .astype("timedelta64[s]").astype(float) / 3600.0) % 24.0
        self.solar_hour = solar_hour

    def _kind(self, i: int, kind: str) -> float:
        """The change's amount when ``kind`` acts at sample i, else 0."""
        c = self.change
        return c.amount if c is not None and c.kind == kind and self.on[i] else 0.0

    def _vents(self, i: int, t_air: float, rh: float) -> float:
        h = self.h
        if self.change is not None and self.change.kind == "controller" and self.on[i]:
            heat = np.clip((t_air - 18.0) / 2.0, 0.0, 1.0)
            return float(max(heat, np.clip((rh - 80.0) / h.rh_band, 0.0, 1.0)))
        heat = np.clip((t_air - h.vent_setpoint) / h.vent_band, 0.0, 1.0)
        humid = np.clip((rh - h.rh_max) / h.rh_band, 0.0, 1.0)
        cold = np.clip((t_air - h.vent_cold) / 4.0, 0.0, 1.0)
        return float(max(heat, humid * cold))

    def _radiation(self, i: int) -> tuple[float, float, float, float, float]:
        """(canopy, floor, air, outer cover, above canopy) absorbed short wave [W m-2]."""
        h, ig = self.h, float(self.w.i_glob[i])
        white = self._kind(i, "whitening") or 1.0
        tau = h.tau_cover * white
        par = nir = (1.0 - h.eta_glob_air) * tau * 0.5 * ig  # Eq. 27, above the canopy
        e1, en = np.exp(-h.k_par * h.lai), np.exp(-h.k_nir * h.lai)
        can = (par * (1 - h.rho_can_par) * ((1 - e1) + e1 * h.rho_flr_par * (1 - e1))  # Eqs. 25-28
               + nir * (1 - h.rho_can_nir) * (1 - en))  # after Eqs. 30-32
        flr = par * (1 - h.rho_flr_par) * e1 + nir * (1 - h.rho_flr_nir) * en  # Eqs. 33-34
        air = h.eta_glob_air * tau * ig  # Eq. 35 (absorbed NIR fractions taken as transmitted)
        cov = h.a_cover * ig  # Eq. 36
        return can, flr, air, cov, par + nir

    def _vapour(self, i: int, t: np.ndarray, vp: float, f: float, dt: float,
                r_above: float) -> tuple[float, float, float, float]:
        """Implicit step of Eq. 10: (new VP, transpiration, condensation, fog) [Pa, kg m-2 s-1]."""
        h, w = self.h, self.w
        t_k = t[AIR] + KELVIN
        cap = M_WATER * h.height / (R_GAS * t_k)  # Eq. 24
        vps_can, vps_cov = saturation_vp(t[CAN]), saturation_vp(t[CIN])
        s_rs = 1.0 / (1.0 + np.exp(-1.0 * (r_above - 5.0)))  # Eq. 50 (day weight)
        c3 = 1.1e-11 * (1 - s_rs) + 6.1e-7 * s_rs
        c4 = 5.2e-6 * (1 - s_rs) + 4.3e-6 * s_rs
        rf_r = (r_above + 4.3) / (r_above + 0.54)  # Eq. 49
        rf_co2 = min(1.5, 1.0 + c3 * (400.0 - 200.0) ** 2)
        rf_vp = min(5.8, 1.0 + c4 * max(vps_can - vp, 0.0) ** 2)
        vec = 2 * RHO_AIR * CP_AIR * h.lai / (L_VAP * GAMMA * (h.r_b + h.r_s_min * rf_r * rf_co2 * rf_vp))
        hec = 1.86 * abs(t[AIR] - t[CIN]) ** (1 / 3) * h.cover_ratio
        switch = 1.0 / (1.0 + np.exp(-0.1 * (vp - vps_cov)))  # Eq. 43, s_MV12 = -0.1
        c_cond = switch * 6.4e-9 * hec
        vp_out = float(self.w.rh_out[i]) / 100.0 * saturation_vp(float(w.t_out[i]))
        c_vent = M_WATER * f / R_GAS  # airMv: M_w f / R (VP1/T1 - VP2/T2)
        fog = self._kind(i, "misting") if 10.0 <= self.solar_hour[i] < 16.0 else 0.0
        num = cap / dt * vp + vec * vps_can + c_vent * vp_out / (float(w.t_out[i]) + KELVIN) \
            + c_cond * vps_cov + fog
        new = num / (cap / dt + vec + c_vent / t_k + c_cond)
        return new, vec * (vps_can - new), c_cond * (new - vps_cov), fog

    def run(self, spinup_days: int = 2) -> Run:
        """Simulate the window; the first day is run ``spinup_days`` times before it, with no
        change acting, so that the soil layers and the cover start consistent."""
        w = self.w
        n = len(w.time)
        t = np.full(N_NODES, float(w.t_out[0]) + 4.0)
        t[list(SO)] = np.linspace(t[AIR], self.t_soil_out, N_SOIL + 2)[1:-1]
        vp = 0.8 * saturation_vp(t[AIR])
        for _ in range(spinup_days):
            t, vp = self._day(t, vp)
        rec = {k: np.empty(n) for k in ("t_air", "vp", "t_can", "r_can", "vent", "t_body")}
        body = t[AIR]
        worst = 0.0
        sub = int(round(60.0 / SUBSTEP))
        for i in range(n):
            for _ in range(sub):
                t, vp, r_above, vent, resid = self._step(i, t, vp, SUBSTEP)
                worst = max(worst, resid)
                k = self._kind(i, "sun_sensor")
                body += (t[AIR] + k * r_above - body) * (1.0 - np.exp(-SUBSTEP / 240.0))
            for key, v in (("t_air", t[AIR]), ("vp", vp), ("t_can", t[CAN]), ("r_can", r_above),
                           ("vent", vent), ("t_body", body)):
                rec[key][i] = v
        return Run(w.time, rec["t_air"], rec["vp"], rec["t_body"], rec["t_can"], rec["r_can"],
                   rec["vent"], worst)

    def _day(self, t: np.ndarray, vp: float) -> tuple[np.ndarray, float]:
        on, self.on = self.on, np.zeros(len(self.on), bool)
        try:
            for i in range(min(1440, len(self.w.time))):
                for _ in range(int(round(60.0 / SUBSTEP))):
                    t, vp, *_ = self._step(i, t, vp, SUBSTEP)
        finally:
            self.on = on
        return t, vp

    def _step(self, i: int, t: np.ndarray, vp: float, dt: float):
        """One backward-Euler sub-step of the heat network from state ``t`` at sample i."""
        h, w = self.h, self.w
        u, t_out, t_sky = float(w.wind[i]), float(w.t_out[i]), float(w.t_sky[i])
        rh = 100.0 * vp / saturation_vp(t[AIR])
        vent = self._vents(i, t[AIR], rh)
        t_mean = 0.5 * (t[AIR] + t_out) + KELVIN
        f_roof = vent * h.roof_ratio * h.c_d / 2.0 * np.sqrt(
            abs(G * h.h_vent * (t[AIR] - t_out) / (2 * t_mean) + h.c_w * u * u))  # Eq. 64
        leak = h.c_leakage * (self._kind(i, "leakage") or 1.0) * max(u, 0.25)  # Eq. 70
        f = f_roof + leak  # Eq. 71
        can, flr, air, cov, r_above = self._radiation(i)
        vp_new, transp, cond, fog = self._vapour(i, t, vp, f, dt, r_above)
        lai_part = np.exp(-h.k_fir * h.lai)
        view_pipe = 0.49
        g = np.array([
            2 * h.alpha_leaf * h.lai,
            1.7 * abs(t[FLR] - t[AIR]) ** (1 / 3) if t[FLR] > t[AIR] else 1.3 * abs(t[AIR] - t[FLR]) ** 0.25,
            1.86 * abs(t[AIR] - t[CIN]) ** (1 / 3) * h.cover_ratio,
            h.k_cover,
            2.0 / (h.h_floor / h.lambda_floor + h.soil_layers[0] / h.lambda_soil),
            *(2 * h.lambda_soil / (a + b) for a, b in zip(h.soil_layers[:-1], h.soil_layers[1:],
                                                           strict=True)),
            _fir(self.a_can, 1.0, h.eps_cover, 1.0, t[CAN], t[CIN]),
            _fir(self.a_can, 1.0, 1.0, 1.0 - view_pipe * self.pipe_area, t[CAN], t[FLR]),
            _fir(1.0, 1.0, h.eps_cover, lai_part * (1 - view_pipe * self.pipe_area), t[FLR], t[CIN]),
            1.99 * self.pipe_area * abs(t[PIPE] - t[AIR]) ** 0.32,
            _fir(self.pipe_area, h.eps_pipe, 1.0, view_pipe * (1 - lai_part), t[PIPE], t[CAN]),
            _fir(self.pipe_area, h.eps_pipe, 1.0, view_pipe, t[PIPE], t[FLR]),
            _fir(self.pipe_area, h.eps_pipe, h.eps_cover, view_pipe * lai_part, t[PIPE], t[CIN]),
            3.0 if self._kind(i, "thermal_mass") else 0.0,
        ])
        lap = (INCIDENCE.T * g) @ INCIDENCE
        src = np.zeros(N_NODES)
        src[CAN] = can - L_VAP * transp
        src[AIR] = air - L_VAP * fog
        src[FLR] = flr
        src[CIN] = L_VAP * cond
        src[CEX] = cov
        heat = self._kind(i, "heater")
        if self._kind(i, "night_heater") and float(w.i_glob[i]) < 10.0:
            heat = self._kind(i, "night_heater")
        src[PIPE] = heat
        bnd = np.zeros(N_NODES)  # conductance to a boundary temperature
        b_t = np.zeros(N_NODES)
        g_co = h.cover_ratio * (2.8 + 1.2 * u)
        g_sky = _fir(1.0, h.eps_cover, 1.0, 1.0, t[CEX], t_sky)
        bnd[CEX], b_t[CEX] = g_co + g_sky, (g_co * t_out + g_sky * t_sky) / (g_co + g_sky)
        bnd[AIR], b_t[AIR] = RHO_AIR * CP_AIR * f, t_out
        last = SO[-1]
        bnd[last] = 2 * h.lambda_soil / (h.soil_layers[-1] + h.h_soil_out)
        b_t[last] = self.t_soil_out
        cap = self.cap.copy()
        if self._kind(i, "thermal_mass"):
            cap[WATER] = self._kind(i, "thermal_mass") * CP_WATER
        a = np.diag(cap / dt) + lap + np.diag(bnd)
        new = np.linalg.solve(a, cap / dt * t + src + bnd * b_t)
        applied = src + bnd * (b_t - new) - lap @ new
        resid = float(np.max(np.abs(cap * (new - t) / dt - applied)))
        if not self._kind(i, "thermal_mass"):
            new[WATER] = new[AIR]  # tanks not there yet: their water will start at air temperature
        return new, vp_new, r_above, vent, resid

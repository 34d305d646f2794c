"""The greenhouse's heat and water balances, integrated in time.

Nodes (all per m2 of floor): air + fast mass ``T_a``, cover ``T_c``, floor/soil surface ``T_f``,
deep soil ``T_d`` (tied to a ground boundary ``T_g``), and the absolute humidity of the air
``c_a`` [kg m-3].

Each sub-step freezes the coefficients (convection, radiation conductances, ventilation flow,
transpiration) at the start state, then takes a backward-Euler (implicit) step of the linear
4-node heat network, solved exactly by elimination, and an implicit step of the vapour balance
with condensation on the cover. Backward Euler is unconditionally stable, so the thin cover
(time constant ~20 s) and the air node (~1 min) need no tiny steps; and because the fluxes are
re-evaluated at the new temperatures with the frozen coefficients, node storage = sum of fluxes
holds to rounding on every sub-step (the balance tests rely on that).

Energy paths (W m-2 of floor, sign = direction in the name):
- short wave: absorbed by the cover, the fast mass, the canopy and the floor;
- canopy: quasi-steady big leaf, its absorbed short wave splits into transpiration (latent, to
  the air's vapour) and sensible heat to the air (negative at night: the crop cools the air);
- convection air→cover (inner), cover→outside (wind), floor→air;
- long wave: cover→sky, cover→surroundings (at t_out), floor→cover, floor→sky through the film;
- conduction floor→deep→ground;
- ventilation and leakage air→outside;
- condensation on the cover (latent heat to the cover) and fog in saturated air (to the air).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from gateway.model.psychrometrics import CP_AIR, KELVIN
from training.simulate import crop, heat, ventilation
from training.simulate.effects import PhysicsDrivers
from training.simulate.plant import Plant

RHO_AIR = 1.2
"""Air density used for heat capacity and ventilation [kg m-3] (constant: closes the balance)."""
R_VAPOUR = 461.5
"""Specific gas constant of water vapour [J kg-1 K-1]."""
K_CONDENSATION = 6.4e-9
"""Mass transfer per unit heat transfer coefficient [kg W-1 s-1 Pa-1 K] (De Zwart 1996)."""
NIGHT_RADIATION = 10.0
"""Outside radiation [W m-2] below which a night-only heater may run."""

FLUXES = (
    # name, unit, meaning
    ("q_solar_cover", "W m-2", "short wave absorbed by the cover"),
    ("q_solar_air", "W m-2", "short wave absorbed by the fast mass (air node)"),
    ("q_solar_crop", "W m-2", "short wave absorbed by the canopy"),
    ("q_solar_floor", "W m-2", "short wave absorbed by the floor"),
    ("q_transpiration", "W m-2", "latent heat of transpiration (canopy to vapour)"),
    ("q_crop_air", "W m-2", "sensible heat canopy -> air"),
    ("q_heater", "W m-2", "injected heater -> air"),
    ("q_fog", "W m-2", "latent heat of fog condensing in the air -> air"),
    ("q_conv_floor_air", "W m-2", "convection floor -> air"),
    ("q_conv_air_cover", "W m-2", "convection air -> cover"),
    ("q_vent", "W m-2", "sensible heat by vent flow air -> outside"),
    ("q_leak", "W m-2", "sensible heat by leakage (incl. injected) air -> outside"),
    ("q_condensation", "W m-2", "latent heat of condensation on the cover -> cover"),
    ("q_lw_floor_cover", "W m-2", "long wave floor -> cover"),
    ("q_conv_cover_out", "W m-2", "convection cover -> outside air"),
    ("q_lw_cover_sky", "W m-2", "long wave cover -> sky"),
    ("q_lw_cover_surr", "W m-2", "long wave cover -> surroundings at t_out"),
    ("q_lw_floor_sky", "W m-2", "long wave floor -> sky through the film"),
    ("q_cond_floor_deep", "W m-2", "conduction floor -> deep soil"),
    ("q_cond_deep_ground", "W m-2", "conduction deep soil -> ground boundary"),
    ("s_air", "W m-2", "heat storage rate of the air + fast mass"),
    ("s_cover", "W m-2", "heat storage rate of the cover"),
    ("s_floor", "W m-2", "heat storage rate of the floor"),
    ("s_deep", "W m-2", "heat storage rate of the deep soil"),
    ("w_transpiration", "kg m-2 s-1", "transpiration"),
    ("w_vent", "kg m-2 s-1", "vapour out by vent flow and leakage"),
    ("w_condensation", "kg m-2 s-1", "condensation on the cover"),
    ("w_fog", "kg m-2 s-1", "fog condensing in the air"),
    ("w_storage", "kg m-2 s-1", "vapour storage rate in the air"),
    ("g_vent", "m3 s-1", "ventilation flow through the vents"),
    ("g_leak", "m3 s-1", "leakage flow including injected extra leakage"),
    ("g_extra", "m3 s-1", "injected extra leakage flow"),
    ("cap_air", "J m-2 K-1", "heat capacity of the air + fast-mass node in use"),
)
FLUX_INDEX = {name: i for i, (name, _, _) in enumerate(FLUXES)}


@dataclass
class State:
    """Node temperatures [°C] and absolute humidity of the air ``c_a`` [kg m-3]."""

    t_a: float
    t_c: float
    t_f: float
    t_d: float
    c_a: float


@dataclass
class SubstepInputs:
    """Drivers at each sub-step midpoint (arrays), and at each output time (for the controller)."""

    t_out: np.ndarray  # [°C]
    c_out: np.ndarray  # [kg m-3]
    i_glob: np.ndarray  # [W m-2]
    wind: np.ndarray  # [m s-1]
    t_sky: np.ndarray  # [°C]
    lai: np.ndarray  # [m2 m-2]
    t_ground: float  # [°C]
    storm_out: np.ndarray  # wind alarm of the vent controller at output times [bool]
    rain_out: np.ndarray  # at output times [0/1]
    time_out: np.ndarray | None = None  # output times [s since the epoch, UTC] (hand-moved vents)


@dataclass
class Trajectory:
    """States at output times, vent positions decided at each output time, and sub-step fluxes."""

    t_a: np.ndarray
    t_c: np.ndarray
    t_f: np.ndarray
    t_d: np.ndarray
    c_a: np.ndarray
    vent_roof: np.ndarray  # [%]
    vent_side: np.ndarray  # [%]
    i_in: np.ndarray  # sub-step inside radiation [W m-2]
    fluxes: np.ndarray  # (n_sub, len(FLUXES))


def saturation_pa(t: float) -> float:
    """Saturation vapour pressure [Pa] at ``t`` [°C] (Tetens; same as the psychrometrics module)."""
    return 610.78 * math.exp(17.2694 * t / (t + 237.3))


def vapour_concentration(t: np.ndarray, rh: np.ndarray) -> np.ndarray:
    """Absolute humidity [kg m-3] of air at ``t`` [°C] and relative humidity ``rh`` [%]."""
    t = np.asarray(t, dtype=float)
    p = 610.78 * np.exp(17.2694 * t / (t + 237.3)) * np.asarray(rh, dtype=float) / 100.0
    return p / (R_VAPOUR * (t + KELVIN))


class _House(NamedTuple):
    """The plant's constants per m2 of floor, used on every sub-step."""

    cover_ratio: float  # cover area per floor area [-]
    height: float  # mean height, volume / floor area [m]
    c_air0: float  # air + fast mass heat capacity [J m-2 K-1]
    c_cov: float  # cover [J m-2 K-1]
    c_flr: float  # floor [J m-2 K-1]
    c_dp: float  # deep soil [J m-2 K-1]
    eps_fc: float  # floor-cover long-wave exchange factor [-]
    eps_fs: float  # floor-sky, through the film [-]
    eps_cs: float  # cover-sky [-]
    eps_cu: float  # cover-surroundings [-]
    cd: float  # vent discharge coefficient with the insect screen [-]


def _house(p: Plant) -> _House:
    a_f = p.floor_area
    height = p.volume / a_f
    cover_ratio = p.cover_area / a_f
    return _House(cover_ratio, height, RHO_AIR * CP_AIR * height + p.fast_capacity,
                  p.cover_capacity * cover_ratio, p.floor_capacity, p.deep_capacity,
                  p.eps_floor * p.eps_cover, p.eps_floor * p.tau_lw, p.eps_cover * p.sky_view,
                  p.eps_cover * (1.0 - p.sky_view), p.cd * p.screen_factor)


def _openings(p: Plant, roof: float, side: float) -> tuple[float, float, float]:
    """Roof and side vent areas [m2] (fixed gaps + openings at ``roof``, ``side`` [%]) and the
    roof opening's height [m]."""
    a_r, a_s, h_r = p.fixed_roof_area, p.fixed_side_area, 0.05
    if p.roof_n:
        a_r += ventilation.roof_area(roof, p.roof_n, p.roof_length, p.roof_width, p.roof_max_angle)
        h_r = max(h_r, p.roof_width * math.sin(math.radians(roof / 100 * p.roof_max_angle)))
    if p.side_n:
        a_s += ventilation.side_area(side, p.side_n, p.side_length, p.side_height)
    return a_r, a_s, h_r


def _vapour_step(ca: float, e_tr: float, g_tot: float, c_out: float, k_cond: float,
                 psat_a: float, psat_c: float, t_ak: float, height: float, dt: float
                 ) -> tuple[float, float, float, float]:
    """Implicit step of the air's vapour balance [kg m-3], with condensation on the cover when
    the air is above its dew point and fog when supersaturated. Returns ``c_new``, the
    condensation, vent and fog rates [kg m-2 s-1]."""
    num = height / dt * ca + e_tr + g_tot * c_out
    den = height / dt + g_tot
    c_new = num / den
    m_cond = 0.0
    if c_new * R_VAPOUR * t_ak > psat_c:
        num += k_cond * psat_c
        den += k_cond * R_VAPOUR * t_ak
        c_new = num / den
        m_cond = k_cond * (c_new * R_VAPOUR * t_ak - psat_c)
    m_vent = g_tot * (c_new - c_out)  # the implicit solution carries this flow
    c_sat = psat_a / (R_VAPOUR * t_ak)
    m_fog = 0.0
    if c_new > c_sat:  # supersaturated: the excess condenses as fog in the air
        m_fog = (c_new - c_sat) * height / dt
        c_new = c_sat
    return c_new, m_cond, m_vent, m_fog


def _solve_network(r: tuple[float, float, float, float], a: tuple[float, float, float, float],
                   k_ac: float, k_fa: float, k_fc: float, k_fd: float
                   ) -> tuple[float, float, float, float]:
    """The backward-Euler 4-node system (air, cover, floor, deep: right sides ``r``, diagonals
    ``a``, couplings ``k``) solved exactly: the deep node eliminated, then the air node, then
    the 2x2 (cover, floor). Returns the new (air, cover, floor, deep) temperatures [°C]."""
    r_a, r_c, r_f, r_d = r
    a_aa, a_cc, a_ff, a_dd = a
    a_ff -= k_fd * k_fd / a_dd
    r_f += k_fd * r_d / a_dd
    pc = a_cc - k_ac * k_ac / a_aa
    qf = a_ff - k_fa * k_fa / a_aa
    b = -k_fc - k_ac * k_fa / a_aa
    s1 = r_c + k_ac * r_a / a_aa
    s2 = r_f + k_fa * r_a / a_aa
    det = pc * qf - b * b
    tc_n = (s1 * qf - b * s2) / det
    tf_n = (pc * s2 - b * s1) / det
    ta_n = (r_a + k_ac * tc_n + k_fa * tf_n) / a_aa
    td_n = (r_d + k_fd * tf_n) / a_dd
    return ta_n, tc_n, tf_n, td_n


class _Series(NamedTuple):
    """Sub-step drivers as Python lists (scalar arithmetic in the loop is faster on floats)."""

    t_out: list
    c_out: list
    i_glob: list
    wind: list
    t_sky: list
    lai: list
    tau: list  # cover transmission with the injected factor [-]
    extra: list  # injected extra leakage [m3 s-1]
    capf: list  # injected heat capacity factor [-]
    heaters: list  # (mask list, power, setpoint, night_only)


def run(plant: Plant, inputs: SubstepInputs, drivers: PhysicsDrivers, state: State,
        step: float, substeps: int, roof0: float = 0.0, side0: float = 0.0) -> Trajectory:
    """Integrate from ``state`` over ``len(inputs.storm_out)`` output times ``step`` [s] apart.

    Index 0 of the output is the initial state; sub-steps ``(k-1)*substeps ...`` fill the
    interval ending at output ``k``.
    """
    n_out = len(inputs.storm_out)
    p, ctrl = plant, plant.controller
    series = _Series(inputs.t_out.tolist(), inputs.c_out.tolist(), inputs.i_glob.tolist(),
                     inputs.wind.tolist(), inputs.t_sky.tolist(), inputs.lai.tolist(),
                     (p.tau_sw * drivers.tau_factor).tolist(), drivers.extra_leak.tolist(),
                     drivers.cap_factor.tolist(),
                     [(mask.tolist(), power, sp, night) for mask, power, sp, night in drivers.heaters])
    n_sub = (n_out - 1) * substeps
    rec = np.empty((n_sub, len(FLUXES)))
    i_in_rec = np.empty(n_sub)
    out = np.empty((n_out, 5))
    vent = np.empty((n_out, 2))
    x = (state.t_a, state.t_c, state.t_f, state.t_d, state.c_a)
    roof, side = roof0, side0
    out[0] = x
    house = _house(p)
    for k in range(1, n_out):
        if ctrl is not None:
            now = 0.0 if inputs.time_out is None else float(inputs.time_out[k - 1])
            roof, side = ctrl.step(x[0], inputs.storm_out[k - 1], inputs.rain_out[k - 1],
                                   roof, side, step, now)
        vent[k - 1] = (roof, side)
        x = _interval(p, house, series, inputs.t_ground, _openings(p, roof, side), x,
                      (k - 1) * substeps, substeps, step / substeps, rec, i_in_rec)
        out[k] = x
    if ctrl is not None:
        now = 0.0 if inputs.time_out is None else float(inputs.time_out[-1])
        roof, side = ctrl.step(x[0], inputs.storm_out[-1], inputs.rain_out[-1], roof, side, step,
                               now)
    vent[n_out - 1] = (roof, side)
    return Trajectory(out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4],
                      vent[:, 0], vent[:, 1], i_in_rec, rec)


def _interval(p: Plant, house: _House, s: _Series, t_g: float,
              openings: tuple[float, float, float], x: tuple, i0: int, m: int, dt: float,
              rec: np.ndarray, i_in_rec: np.ndarray) -> tuple:
    """``m`` sub-steps of ``dt`` [s] from state ``x`` (t_a, t_c, t_f, t_d, c_a), the vents fixed at
    ``openings``; writes sub-step rows ``i0 ...`` of ``rec`` and ``i_in_rec``; returns the state."""
    ta, tc, tf, td, ca = x
    a_r, a_s, h_r = openings
    cover_ratio, height, c_air0, c_cov, c_flr, c_dp, eps_fc, eps_fs, eps_cs, eps_cu, cd = house
    t_out, c_out, i_glob, wind, t_sky, lai_s, tau, extra, capf, heaters = s
    k_fd, k_dg, a_f, rhocp = p.k_floor_deep, p.k_deep_ground, p.floor_area, RHO_AIR * CP_AIR
    for i in range(i0, i0 + m):
        t_o, u, t_s, lai, i_g = t_out[i], wind[i], t_sky[i], lai_s[i], i_glob[i]
        t_ak = ta + KELVIN
        c_a_cap = c_air0 * capf[i]

        # Short wave.
        i_in = tau[i] * i_g * p.sun_ratio
        q_sc = p.alpha_sw * i_g * p.sun_ratio
        q_sa = p.f_sw_air * i_in
        icpt = crop.intercepted(lai, p.k_ext)
        q_scr = p.alpha_crop * icpt * (1.0 - p.f_sw_air) * i_in
        q_sf = p.floor_alpha_sw * (1.0 - icpt) * (1.0 - p.f_sw_air) * i_in

        # Transpiration, explicit at the start state.
        psat_a = saturation_pa(ta)
        vpd = max(psat_a - ca * R_VAPOUR * t_ak, 0.0)
        lam = 4185.5 * (597.0 - 0.56 * ta)
        q_tr = crop.transpiration(q_scr, ta, vpd, lai, p.r_b, p.r_s_min, RHO_AIR)
        e_tr = q_tr / lam

        # Air exchange.
        g_v = ventilation.kittas_flow(a_r, a_s, ta - t_o, t_o, u, p.vent_height, cd, p.cw, h_r)
        g_l = ventilation.leakage_flow(p.volume, p.leak_ach, p.leak_ach_wind, u) + extra[i]
        g_tot = (g_v + g_l) / a_f  # [m s-1] per m2 of floor

        h_ci = heat.natural_convection(ta - tc, p.h_in_a, p.h_in_b)
        c_new, m_cond, m_vent, m_fog = _vapour_step(
            ca, e_tr, g_tot, c_out[i], K_CONDENSATION * h_ci * cover_ratio, psat_a,
            saturation_pa(tc), t_ak, height, dt)

        q_h = 0.0  # heater(s)
        for mask, power, sp, night in heaters:
            if mask[i] and not (night and i_g > NIGHT_RADIATION):
                q_h += power if sp != sp else power * min(max(sp - ta, 0.0), 1.0)

        # Heat network conductances [W m-2 floor K-1], frozen over the sub-step.
        k_ac = h_ci * cover_ratio
        k_co = heat.wind_convection(u, p.h_out_a, p.h_out_b) * cover_ratio
        k_cs = heat.radiative_conductance(tc, t_s, eps_cs) * cover_ratio
        k_cu = heat.radiative_conductance(tc, t_o, eps_cu) * cover_ratio
        k_fa = heat.floor_convection(tf, ta, p.h_floor_up, p.h_floor_down)
        k_fc = heat.radiative_conductance(tf, tc, eps_fc)
        k_fs = heat.radiative_conductance(tf, t_s, eps_fs)
        k_v = rhocp * g_tot

        q_crop_air = q_scr - q_tr
        ta_n, tc_n, tf_n, td_n = _solve_network(
            (c_a_cap / dt * ta + q_sa + q_crop_air + q_h + lam * m_fog + k_v * t_o,
             c_cov / dt * tc + q_sc + lam * m_cond + (k_co + k_cu) * t_o + k_cs * t_s,
             c_flr / dt * tf + q_sf + k_fs * t_s,
             c_dp / dt * td + k_dg * t_g),
            (c_a_cap / dt + k_fa + k_ac + k_v, c_cov / dt + k_ac + k_fc + k_co + k_cs + k_cu,
             c_flr / dt + k_fa + k_fc + k_fs + k_fd, c_dp / dt + k_fd + k_dg),
            k_ac, k_fa, k_fc, k_fd)

        q_vl = k_v * (ta_n - t_o)
        share_v = g_v / (g_v + g_l) if g_v + g_l > 0.0 else 0.0
        rec[i] = (
            q_sc, q_sa, q_scr, q_sf, q_tr, q_crop_air, q_h, lam * m_fog, k_fa * (tf_n - ta_n),
            k_ac * (ta_n - tc_n), q_vl * share_v, q_vl * (1.0 - share_v), lam * m_cond,
            k_fc * (tf_n - tc_n), k_co * (tc_n - t_o), k_cs * (tc_n - t_s),
            k_cu * (tc_n - t_o), k_fs * (tf_n - t_s), k_fd * (tf_n - td_n), k_dg * (td_n - t_g),
            c_a_cap * (ta_n - ta) / dt, c_cov * (tc_n - tc) / dt, c_flr * (tf_n - tf) / dt,
            c_dp * (td_n - td) / dt,
            e_tr, m_vent, m_cond, m_fog, height * (c_new - ca) / dt,
            g_v, g_l, extra[i], c_a_cap,
        )
        i_in_rec[i] = i_in
        ta, tc, tf, td, ca = ta_n, tc_n, tf_n, td_n, c_new
    return ta, tc, tf, td, ca


def interval_means(values: np.ndarray, substeps: int) -> np.ndarray:
    """Means of sub-step rows over each output interval; row 0 (no interval ends there) is NaN."""
    n_sub = values.shape[0]
    shape = (n_sub // substeps, substeps) + values.shape[1:]
    means = values.reshape(shape).mean(axis=1)
    pad = np.full((1,) + values.shape[1:], np.nan)
    return np.concatenate([pad, means])

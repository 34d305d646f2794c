"""An independent reference for the prototype model: fine RK4 of III.9–III.22 (issue 10).

Written from the thesis's equations, not from ``gateway.model`` (no flux term, no exponential
step is imported), so that data made here test the model's integration instead of repeating it:

    rho_a V/S_f dT_in/dt = C_solar I - C_cnv_cnd U (T_in - T_a) - C_loss rho_a (T_in - T_a)
                           - C_thermal h_o (T_in - T_sky)                          (III.14–III.22)
    U = (1/h_o + 1/h_i)^-1,  h_o = 2.8 + 1.2 W,  h_i = 5.2 |T_in - T_a|^0.33       (III.8–III.10)
    T_sky from the outside humidity and cloudiness (gateway/model/sky.py, in place of III.13)

with rho_a = gamma_0 = 1.205 kg m-3, V = 0.76 m3, S_f = 0.68 m2 (table 2). T_sky is a driver (it
depends on the weather only, never on the state), so it is taken from the model's sky module:
the cloud fraction is what the kit's own minute rows at the Biskra site give
(``sky.cloud_fraction``), moving linearly between minute midpoints, and Brutsaert's clear sky
follows the continuous T_a and RH. The drivers vary
continuously: linear between the samples of the 5-minute Bleiswijk file (scaled towards a
Biskra winter: radiation × 1.4, temperature + 3 °C). The state is integrated with classical RK4
at ``h`` seconds (1 s: converged to ~2e-8 K, ``tests/test_step_bias.py``), and the kit's rows
are either the per-minute means (what the kit sends: every channel averaged over the minute)
or the instantaneous values at the minute marks.

For the bias study the reference can also freeze parts of the physics over each ``hold``
seconds, as the zero-order-hold step does: the drivers (``freeze_drivers``), the inside
coefficient h_i (``freeze_hi``), or the air density (``rho="moist_frozen"``, with
``rho="moist"`` the moist-air density of the inside air following T_in, III.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gateway.greenhouse import load_greenhouse
from gateway.model import sky
from training.weather import load_bleiswijk

ASSUMED = {"c_solar": 5.8e-5, "c_cnv_cnd": 5.3e-4, "c_loss": 1.7e-4, "c_thermal": 2.2e-5}
"""Assumed parameter values of table 4."""
GAMMA_0, VOLUME, FLOOR = 1.205, 0.76, 0.68  # table 2
KNOT_S = 300.0  # the weather file's step
START = np.datetime64("2009-10-20T00:00:00", "s")  # midnight UTC, a sunny then a mixed day
_SITE = load_greenhouse("biskra-prototype").site
SITE = (_SITE.latitude, _SITE.longitude)
"""The prototype's site (latitude, longitude) [deg]: where the cloudiness is read."""


@dataclass(frozen=True)
class Weather:
    """Driver knots every KNOT_S seconds from START: T_a [°C], I [W m-2], W [m s-1], RH [%]."""

    t_out: np.ndarray
    i_glob: np.ndarray
    wind: np.ndarray
    rh_out: np.ndarray

    def at(self, seconds: np.ndarray) -> dict[str, np.ndarray]:
        """The drivers linearly interpolated at ``seconds`` after START."""
        knots = np.arange(len(self.t_out)) * KNOT_S
        return {k: np.interp(seconds, knots, getattr(self, k))
                for k in ("t_out", "i_glob", "wind", "rh_out")}


def biskra_weather(days: float = 2.0, first_day: int = 0) -> Weather:
    """``days`` of the 5-minute Bleiswijk file from midnight UTC, scaled to a Biskra winter."""
    w = load_bleiswijk()
    a = int(np.searchsorted(w["time"], START)) + first_day * 288
    b = a + int(round(days * 86400 / KNOT_S)) + 1
    return Weather(w["t_out"][a:b] + 3.0, w["i_glob"][a:b] * 1.4, w["wind"][a:b], w["rh_out"][a:b])


def _moist_density(t_in: float, rh_out: float, t_out: float) -> float:
    """Moist-air density [kg m-3] of inside air at t_in [°C] holding the outside vapour
    (p_atm 101 kPa, table 2): the ideal-gas mixture of docs/model-notes.md §1."""
    p_w = 0.61078 * math.exp(17.2694 * t_out / (t_out + 237.3)) * rh_out / 100.0
    return 101.0e3 / (287.055 * (t_in + 273.15)) * (1.0 - 0.378 * p_w / 101.0)


def integrate(
    weather: Weather,
    theta: dict[str, float] = ASSUMED,
    h: float = 1.0,
    seconds: float | None = None,
    hold: float = 60.0,
    freeze_drivers: bool = False,
    freeze_hi: bool = False,
    rho: str = "constant",
    site: tuple[float, float] | None = SITE,
    sampling: str = "mean",
    row_step: float = 60.0,
) -> np.ndarray:
    """T_in [°C] every ``h`` seconds from T_in = T_a at START, by classical RK4 (``seconds``
    long, default the whole weather span). ``hold`` must be a multiple of ``h``. ``site``:
    where the cloudiness is read (None: the sky module's default cloud fraction); ``sampling``,
    ``row_step`` [s]: the kit rows (``kit_rows``) the cloudiness is read from, as the model will
    read it."""
    if rho not in ("constant", "moist", "moist_frozen"):
        raise ValueError(f"rho must be constant, moist or moist_frozen, got {rho!r}")
    c_s, c_c = theta["c_solar"], theta["c_cnv_cnd"]
    c_l, c_t = theta["c_loss"], theta["c_thermal"]
    t_o, i_g = weather.t_out.tolist(), weather.i_glob.tolist()
    w_v, r_h = weather.wind.tolist(), weather.rh_out.tolist()
    last = len(t_o) - 2
    span = (len(t_o) - 1) * KNOT_S if seconds is None else seconds
    n = int(round(span / h))
    per_hold = int(round(hold / h))

    # every h/2: where RK4's stages read it
    t_sky_half = sky_temperatures(weather, n, h / 2.0, site, sampling, row_step).tolist()

    def drivers(t: float) -> tuple[float, float, float, float, float]:
        k = min(int(t // KNOT_S), last)
        f = (t - KNOT_S * k) / KNOT_S
        return (t_o[k] + (t_o[k + 1] - t_o[k]) * f, i_g[k] + (i_g[k + 1] - i_g[k]) * f,
                w_v[k] + (w_v[k + 1] - w_v[k]) * f, r_h[k] + (r_h[k + 1] - r_h[k]) * f,
                t_sky_half[int(round(2.0 * t / h))])

    def rate(t: float, temp: float, frozen: tuple) -> float:
        t_a, i, w, rh, t_sky = frozen[0] if freeze_drivers else drivers(t)
        h_o = 2.8 + 1.2 * w  # III.9
        dt_i = (frozen[1] if freeze_hi else temp) - t_a
        h_i = 5.2 * abs(dt_i) ** 0.33  # III.10
        u = h_o * h_i / (h_o + h_i) if h_i > 0.0 else 0.0  # III.8
        if rho == "constant":
            dens = GAMMA_0
        else:
            dens = frozen[2] if rho == "moist_frozen" else _moist_density(temp, rh, t_a)
        q = c_s * i - c_c * u * (temp - t_a) - c_l * dens * (temp - t_a) - c_t * h_o * (temp - t_sky)
        return q / (dens * VOLUME / FLOOR)  # III.14

    out = np.empty(n + 1)
    temp = t_o[0]
    out[0] = temp
    frozen: tuple = (drivers(0.0), temp, GAMMA_0)
    for k in range(n):
        t = k * h
        if k % per_hold == 0:  # what a zero-order hold would freeze for the next `hold` s
            d = drivers(t)
            frozen = (d, temp, _moist_density(temp, d[3], d[0]))
        k1 = rate(t, temp, frozen)
        k2 = rate(t + 0.5 * h, temp + 0.5 * h * k1, frozen)
        k3 = rate(t + 0.5 * h, temp + 0.5 * h * k2, frozen)
        k4 = rate(t + h, temp + h * k3, frozen)
        temp += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out[k + 1] = temp
    return out


def sky_temperatures(weather: Weather, n: int, dt: float, site: tuple[float, float] | None,
                     sampling: str = "mean", row_step: float = 60.0) -> np.ndarray:
    """T_sky [°C] at 0, dt, ..., 2 n dt seconds: Brutsaert's clear sky from the continuous T_a
    and RH, and the cloud fraction that the kit's rows every ``row_step`` seconds give, moving linearly
    between the rows: means over each row's step (``mean``) or the values at the row marks
    (``instant``). The cloudiness is a
    running estimate made from the sampled radiation, so it depends on how it was sampled."""
    span = 2 * n * dt
    marks = np.arange(int(span // row_step) + 2) * row_step
    if sampling == "mean":  # the exact mean of the piecewise-linear radiation over each row
        sub = marks[:, None] + (np.arange(60) + 0.5)[None, :] * (row_step / 60.0)
        i_rows, at = weather.at(sub)["i_glob"].mean(axis=1), marks + 0.5 * row_step
    else:
        i_rows, at = weather.at(marks)["i_glob"], marks
    cloud = sky.cloud_fraction(START + marks.astype("timedelta64[s]"), i_rows, site, row_step)
    t = np.arange(2 * n + 1) * dt
    w = weather.at(t)
    return sky.sky_temperature(w["t_out"], w["rh_out"], np.interp(t, at, cloud))


def kit_rows(weather: Weather, trajectory: np.ndarray, h: float, step: float,
             sampling: str) -> dict[str, np.ndarray]:
    """Kit columns every ``step`` seconds from a trajectory sampled every ``h`` seconds:
    ``mean`` = the mean over [t, t + step) of every channel (trapezoid on the fine grid for
    T_in, exact for the piecewise-linear drivers), ``instant`` = the values at t."""
    m = int(round(step / h))
    n = (len(trajectory) - 1) // m
    start = np.arange(n) * step
    if sampling == "instant":
        cols = weather.at(start)
        cols["t_in"] = trajectory[: n * m : m].copy()
    elif sampling == "mean":
        # the drivers are linear between knots and steps of 60 or 300 s never straddle a knot:
        # the midpoint rule integrates them exactly
        sub = start[:, None] + (np.arange(60) + 0.5)[None, :] * (step / 60)
        cols = {k: v.mean(axis=1) for k, v in weather.at(sub).items()}
        seg = 0.5 * (trajectory[: n * m] + trajectory[1 : n * m + 1])
        cols["t_in"] = seg.reshape(n, m).mean(axis=1)
    else:
        raise ValueError(f"sampling must be instant or mean, got {sampling!r}")
    return cols


def time_axis(n: int, step: float) -> np.ndarray:
    """datetime64[s] of ``n`` rows every ``step`` seconds from START."""
    return START + (np.arange(n) * step).astype("timedelta64[s]")

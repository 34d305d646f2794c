"""Test data: an independent two-node greenhouse generator (air + floor/crop mass).

Not product code. Written from scratch for a generality study of `gateway diagnose`; shares no code with
training/simulate. Physics choices (deliberately other than the reference simulator's):

- sky: Brunt clear-sky emissivity 0.52 + 0.065 sqrt(e_a/hPa), cloud fraction from the clearness
  index (measured / Haurwitz clear-sky radiation; relaxing over the night from the last daylight
  value towards 0.75), Crawford-Duchon cloud blend eps = c + (1 - c) eps_clear; T_sky = eps^(1/4) T_out.
- cover: quasi-steady energy balance (Newton) between inside convection (free convection
  1.52 |dT|^(1/3)), outside convection (McAdams 5.7 + 3.8 u), long-wave to the sky, long-wave
  from the floor/crop (partly transparent PE: tau_lw), and a little absorbed sun.
- air: convection with the cover and the mass, air exchange = wind-driven leakage + vents
  (house: Bernoulli wind + stack flow through roof/side openings, proportional vent controller),
  a small direct solar share (structure).
- mass (floor + crop): absorbed sun, convection, long-wave, conduction to a deep soil (house) or
  to the outside air under a table (box), latent heat of transpiration/evaporation.
- vapour: dynamic absolute humidity balance, crop transpiration with a light-dependent stomatal
  resistance (house), tray evaporation (box), condensation on the cover.
- sensors: AR(1) noise, a constant offset, 0.1 K / 0.1 % quantisation; DHT-like RH.

Weather: the shipped Bleiswijk file (Oct-Dec 2009, read here directly); default window
2009-10-20 + 10 days (the sunniest part of the file). Command line: ``python tests/twonode.py
--plant house --effect sunsensor --at 2009-10-26T10:20 --amp 0.006 --out x.csv``.

Effects (from --at): whitening (transmission x f), door (extra air changes), heater (constant or
night-only, on the air), barrels (a water node coupled to the air), sunsensor (a sensor body
heated by inside radiation, with a 4-min lag, RH read at the body temperature), drift (K/day);
outside the diagnosis library: misting (amp W m-2 of evaporative cooling of the air, its vapour
added, 11-15 h UTC), controller (house vents from 13 °C, full at 16 °C, instead of 17/24 °C),
thermostat (a heated house: heating of the air to amp °C, 60 W m-2 K-1 below it, at most
150 W m-2, evaluated every 10 s; tests/generality/heated_study.py runs it from the start).
"""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path

import numpy as np

SIGMA = 5.67e-8
CP = 1005.0
RHO = 1.2
LV = 2.45e6
RV = 461.5
G = 9.81
WEATHER = (Path(__file__).resolve().parent.parent / "training" / "data" / "bleiswijk"
           / "bleiswijk_weather_5min.csv.gz")
T0 = np.datetime64("2009-10-19T23:00:00", "s")  # file is CET


def es(t):  # Tetens, Pa
    return 610.78 * np.exp(17.27 * t / (t + 237.3))


def xsat(t):  # saturated absolute humidity kg m-3
    return es(t) / (RV * (t + 273.15))


def read_weather(start, days, step=60):
    rows = []
    with gzip.open(WEATHER, "rt") as f:
        for i, line in enumerate(f):
            if i < 3:
                continue
            p = line.split(",")
            rows.append((float(p[0]), float(p[1]), float(p[2]), float(p[4]), float(p[7])))
    a = np.array(rows)
    tt = T0 + a[:, 0].astype("timedelta64[s]")
    t_abs = tt.astype(np.int64).astype(float)
    s0 = np.datetime64(start, "s").astype(np.int64)
    grid = s0 + np.arange(0, days * 86400, step)
    g = grid.astype(float)
    names = ["_", "t_out", "vp", "wind", "i_glob"]
    out = {k: np.interp(g, t_abs, a[:, j]) for j, k in enumerate(names)}
    out["time"] = grid.astype("datetime64[s]")
    out["rh_out"] = np.clip(100 * out["vp"] / es(out["t_out"]), 5, 100)
    return out


def sun_elevation_sin(time, lat=52.03, lon=4.53):
    t = time.astype("datetime64[s]")
    doy = ((t - t.astype("datetime64[Y]")).astype("timedelta64[D]").astype(int) + 1)
    hours = (t - t.astype("datetime64[D]")).astype(float) / 3600.0
    decl = np.radians(23.45) * np.sin(2 * np.pi * (284 + doy) / 365)
    ha = np.radians(15 * (hours + lon / 15 - 12))
    la = np.radians(lat)
    return np.sin(la) * np.sin(decl) + np.cos(la) * np.cos(decl) * np.cos(ha)


def sky_temperature(w, site=(52.03, 4.53)):
    s = sun_elevation_sin(w["time"], *site)
    clear = np.where(s > 0.05, 1098 * s * np.exp(-0.057 / np.maximum(s, 0.05)), 0.0)
    kt = np.where(clear > 50, np.clip(w["i_glob"] / np.maximum(clear, 1), 0, 1), np.nan)
    cloud = np.clip(1.0 - (kt - 0.25) / 0.5, 0, 1)  # kt 0.75 clear, 0.25 overcast
    # carry the last daylight value through the night relaxing towards 0.75, see below), start at half cover
    last = 0.5
    for i in range(len(cloud)):
        if np.isnan(cloud[i]):  # night: relax from the last daylight value towards a
            last += (0.75 - last) / 180.0  # climatological 0.75 (NL autumn), 3-h time constant
            cloud[i] = last
        else:
            last = 0.98 * last + 0.02 * cloud[i]
            cloud[i] = last
    e_hpa = w["vp"] / 100
    eps_clear = 0.52 + 0.065 * np.sqrt(e_hpa)
    eps = np.clip(cloud + (1 - cloud) * eps_clear, 0.5, 1.0)  # Crawford & Duchon (1999)
    return eps ** 0.25 * (w["t_out"] + 273.15) - 273.15, cloud


PLANTS = {
    "house": dict(height=3.5, cover_ratio=1.35, tau_sw=0.62, tau_lw=0.25, alpha_cover=0.08,
                  c_mass=55e3, a_mass=0.65, a_air=0.06, k_ground=2.5, t_deep=12.0,
                  leak0=0.35, leak_u=0.25, lai=2.2, floor=877.0,
                  a_roof=5 * 8.36 * 0.73, a_side=2 * 32.75 * 1.9, vent_on=17.0, vent_full=24.0),
    "box": dict(height=0.76 / 0.68, cover_ratio=5.0, tau_sw=0.80, tau_lw=0.45, alpha_cover=0.06,
                c_mass=9e3, a_mass=0.55, a_air=0.10, k_ground=3.0, t_deep=None,
                leak0=1.5, leak_u=0.9, lai=0.0, floor=0.68),
}


def _cover(p, ta, to, tm, tsk, u, ig):
    """Cover temperature [°C], quasi-steady (Newton on its balance), and the inside convection
    coefficient [W m-2 K-1] at it."""
    hco = 5.7 + 3.8 * u
    tc = 0.5 * (ta + to)
    for _k in range(4):
        tck = tc + 273.15
        hci = 1.52 * abs(ta - tc) ** (1 / 3) + 0.5
        f = (hci * (ta - tc) + hco * (to - tc) + 0.9 * SIGMA * (tsk ** 4 - tck ** 4)
             + (1 - p["tau_lw"]) * 0.9 * SIGMA * ((tm + 273.15) ** 4 - tck ** 4) / p["cover_ratio"]
             + p["alpha_cover"] * ig)
        df = -hci - hco - 4 * 0.9 * SIGMA * tck ** 3 * (1 + (1 - p["tau_lw"]) / p["cover_ratio"])
        tc = tc - f / df
    return tc, 1.52 * abs(ta - tc) ** (1 / 3) + 0.5


def _air_exchange(p, plant, ta, to, u, extra, vr, vs):
    """Leakage (+ ``extra`` air changes [h-1]) and, in the house, the vents' wind and stack flow
    at openings ``vr``, ``vs`` [0-1]: [m3 m-2 s-1]."""
    n_leak = p["leak0"] + p["leak_u"] * u + extra  # h-1
    g_flow = n_leak * p["height"] / 3600
    if plant == "house":
        dT = max(ta - to, 0.0)
        a_r, a_s = vr * p["a_roof"], vs * p["a_side"]
        wind_flow = 0.62 * 0.5 * a_r * np.sqrt(0.09) * u  # Bernoulli wind, Cw = 0.09
        stack = 0.62 * (a_r * a_s / np.sqrt(a_r ** 2 + a_s ** 2 + 1e-9)) * np.sqrt(
            2 * G * 2.5 * dT / (ta + 273.15)) if a_s > 0 else 0.0
        g_flow += (np.sqrt(wind_flow ** 2 + stack ** 2)) / p["floor"]
    return g_flow


def _mass_rate(p, plant, tm, tc, tsk, to, x, iin, q_mass):
    """The mass node's rate of change [K s-1] and the evaporation from it [kg m-2 s-1]."""
    tmk, tck = tm + 273.15, tc + 273.15
    lw = (p["tau_lw"] * 0.95 * SIGMA * (tsk ** 4 - tmk ** 4)
          + (1 - p["tau_lw"]) * 0.9 * SIGMA * (tck ** 4 - tmk ** 4))
    if p["t_deep"] is None:
        q_g = p["k_ground"] * (to - tm)
    else:
        q_g = p["k_ground"] * (p["t_deep"] - tm)
    if plant == "house":
        rs = 80 + 20000 / (iin + 50)
        gv = p["lai"] / (rs + 150) * 0.5
    else:
        gv = 0.0008
    evap = max(gv * (xsat(tm) - x), 0.0)
    return (p["a_mass"] * iin - q_mass + lw + q_g - LV * evap) / p["c_mass"], evap


def simulate(plant, start, days, effect=None, at=None, amp=None, seed=1, weather=None,
             site=(52.03, 4.53)):
    """``weather``: arrays (time, t_out, rh_out, vp [Pa], wind, i_glob) on a 60 s grid to use
    instead of the Bleiswijk file (start and days are then ignored); ``site``: (lat, lon)."""
    p = PLANTS[plant]  # seed: the plant is deterministic, only the sensors are noisy
    w = read_weather(start, days) if weather is None else dict(weather)
    t_sky, cloud = sky_temperature(w, site)
    n = len(w["time"])
    tsec = (w["time"] - w["time"][0]).astype(float)
    tau_at = None if at is None else float((np.datetime64(at, "s") - w["time"][0]).astype(float))
    on = np.zeros(n, bool) if tau_at is None else tsec >= tau_at
    h = p["height"]
    ca = RHO * CP * h  # air only
    ta, tm, tw = w["t_out"][0] + 3, w["t_out"][0] + 4, w["t_out"][0] + 4
    x = 0.8 * xsat(ta)
    ts = ta
    c_w = 0.0
    hw = 0.0
    rec = {k: np.zeros(n) for k in ("ta", "tm", "x", "ts", "iin", "vr", "vs", "tc", "G")}
    dt = 10.0
    sub = int(60 / dt)
    vr = vs = 0.0
    hour = (w["time"] - w["time"].astype("datetime64[D]")).astype("timedelta64[s]").astype(float) / 3600
    for i in range(n):
        to, u, ig = w["t_out"][i], w["wind"][i], w["i_glob"][i]
        xo = w["rh_out"][i] / 100 * xsat(to)
        tsk = t_sky[i] + 273.15
        tau = p["tau_sw"] * (amp if effect == "whitening" and on[i] else 1.0)
        iin = tau * ig
        if effect == "barrels" and on[i]:
            c_w, hw = amp, (10.0 if plant == "house" else 7.0)
        extra = amp if effect == "door" and on[i] else 0.0
        heat = 0.0
        if effect == "heater" and on[i]:
            heat = amp
        if effect == "nightheater" and on[i] and ig < 10:
            heat = amp
        thermostat = effect == "thermostat" and on[i]
        # vent controller (house), evaluated every minute on the air temperature
        mist = amp if effect == "misting" and on[i] and 11.0 <= hour[i] < 15.0 else 0.0
        if plant == "house":
            other = effect == "controller" and on[i]
            v_on, v_full = (13.0, 16.0) if other else (p["vent_on"], p["vent_full"])
            vr = float(np.clip((ta - v_on) / (v_full - v_on), 0, 1))
            vs = float(np.clip((ta - v_on - 3) / (v_full - v_on), 0, 1))
        for _ in range(sub):
            tc, hci_c = _cover(p, ta, to, tm, tsk, u, ig)
            q_cov = p["cover_ratio"] * hci_c * (tc - ta)
            g_flow = _air_exchange(p, plant, ta, to, u, extra, vr, vs)  # m3 m-2 s-1
            q_vent = RHO * CP * g_flow * (to - ta)
            hm = 1.8 * abs(tm - ta) ** (1 / 3) + 1.0
            q_mass = hm * (tm - ta)
            q_w = hw * (tw - ta)
            if thermostat:  # pipe heating to the setpoint, proportional and capped
                heat = min(max(60.0 * (amp - ta), 0.0), 150.0)
            dta = (q_cov + q_vent + q_mass + q_w + heat - mist + p["a_air"] * iin) / ca
            dtm, evap = _mass_rate(p, plant, tm, tc, tsk, to, x, iin, q_mass)
            cond = max((x - xsat(tc)) * p["cover_ratio"] * hci_c / (RHO * CP) * 1.0, 0.0)
            dx = (evap + mist / LV - g_flow * (x - xo) - cond) / h
            ta += dt * dta
            tm += dt * dtm
            x = min(x + dt * dx, 1.02 * xsat(ta))
            if c_w > 0:
                tw += dt * hw * (ta - tw) / c_w
            else:
                tw = ta
            # sensor body heated by inside radiation (4-min lag)
            k_s = amp if effect == "sunsensor" and on[i] else 0.0
            ts += dt * (ta + k_s * iin - ts) / 240.0
        for k, v in (("ta", ta), ("tm", tm), ("x", x), ("ts", ts), ("iin", iin), ("vr", vr),
                     ("vs", vs), ("tc", tc), ("G", g_flow)):
            rec[k][i] = v
    return w, rec, on, tsec, t_sky, cloud


def ar1(rng, n, sigma, tau_steps):
    a = np.exp(-1 / tau_steps)
    e = rng.normal(0, sigma * np.sqrt(1 - a * a), n)
    out = np.empty(n)
    acc = rng.normal(0, sigma)
    for i in range(n):
        acc = a * acc + e[i]
        out[i] = acc
    return out


def sensors(plant, w, rec, on, tsec, effect, amp, tau_at, seed):
    rng = np.random.default_rng(seed + 100)
    n = len(tsec)
    t_body = rec["ts"].copy()
    if effect == "drift":
        t_body_read = t_body + np.where(on, amp * (tsec - tau_at) / 86400, 0.0)
    else:
        t_body_read = t_body
    e_in = rec["x"] * RV * (rec["ta"] + 273.15)
    rh = 100 * e_in / es(t_body)  # RH at the sensor body's temperature
    q = lambda v, r=0.1: np.round(v / r) * r  # noqa: E731
    out = {
        "t_in": q(t_body_read + 0.15 + ar1(rng, n, 0.06, 5)),
        "rh_in": np.clip(q(rh + 1.5 + ar1(rng, n, 0.8, 10)), 0, 100),
        "t_out": q(w["t_out"] - 0.1 + ar1(rng, n, 0.06, 5)),
        "rh_out": np.clip(q(w["rh_out"] + ar1(rng, n, 0.8, 10)), 0, 100),
        "i_glob": np.maximum(np.round(w["i_glob"] * 1.02 + rng.normal(0, 2, n)), 0),
        "wind": np.maximum(q(w["wind"] + rng.normal(0, 0.2, n)), 0),
    }
    if plant == "house":
        out["i_in"] = np.maximum(np.round(rec["iin"] * (1 + rng.normal(0, 0.03, n)) + rng.normal(0, 2, n)), 0)
        out["t_soil"] = q(rec["tm"] + 0.2 + ar1(rng, n, 0.05, 5))
        out["vent_roof"] = np.round(100 * rec["vr"])
        out["vent_side"] = np.round(100 * rec["vs"])
        out["lai"] = np.full(n, PLANTS["house"]["lai"])
    return out


def write_kit_csv(path, plant, start="2009-10-20T00:00", days=10.0, effect=None, at=None, amp=None,
                  seed=1, step=60):
    """Simulate ``plant`` ("house" or "box") and write a kit CSV (docs/data-format.md) to ``path``."""
    w, rec, on, tsec, _, _ = simulate(plant, start, days, effect, at, amp, seed)
    tau_at = None if at is None else float((np.datetime64(at, "s") - w["time"][0]).astype(float))
    cols = sensors(plant, w, rec, on, tsec, effect, amp, tau_at, seed)
    names = list(cols)
    with open(path, "w") as f:
        f.write("time," + ",".join(names) + "\n")
        for i in range(0, len(tsec), max(step // 60, 1)):
            f.write(str(w["time"][i]) + "Z," + ",".join(f"{cols[c][i]:.6g}" for c in names) + "\n")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--plant", choices=["house", "box"], required=True)
    ap.add_argument("--start", default="2009-10-20T00:00")
    ap.add_argument("--days", type=float, default=10)
    ap.add_argument("--effect", default="none")
    ap.add_argument("--at", default=None)
    ap.add_argument("--amp", type=float, default=None)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--step", type=int, default=60, help="output step [s]")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    eff = None if a.effect == "none" else a.effect
    w, rec, on, tsec, t_sky, cloud = simulate(a.plant, a.start, a.days, eff, a.at, a.amp, a.seed)
    tau_at = None if a.at is None else float((np.datetime64(a.at, "s") - w["time"][0]).astype(float))
    cols = sensors(a.plant, w, rec, on, tsec, eff, a.amp, tau_at, a.seed)
    k = a.step // 60
    idx = np.arange(0, len(tsec), k)
    names = list(cols)
    with open(a.out, "w") as f:
        f.write("time," + ",".join(names) + "\n")
        for i in idx:
            f.write(str(w["time"][i]) + "Z," + ",".join(f"{cols[c][i]:.6g}" for c in names) + "\n")
    truth = {"plant": a.plant, "effect": a.effect, "at": a.at, "amp": a.amp,
             "ta_mean": float(rec["ta"].mean()), "ta_minus_to": float((rec["ta"] - w["t_out"]).mean()),
             "ta_max": float(rec["ta"].max()),
             "ach_mean": float((rec["G"] / PLANTS[a.plant]["height"] * 3600).mean()),
             "vent_open_frac": float((rec["vr"] > 0).mean()), "rh_mean": float(np.mean(cols["rh_in"])),
             "tsky_minus_tout": float((t_sky - w["t_out"]).mean()), "cloud_mean": float(cloud.mean())}
    with open(a.out.replace(".csv", ".truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    print(json.dumps(truth))


if __name__ == "__main__":
    main()

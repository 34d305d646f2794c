"""Why ``make demo`` fits 9.85 W m-2 for its 25 W m-2 heater (docs/effects.md, "What a flux
amplitude's W m-2 are"). ``python -m training.demo_heater [--out DIR]`` (about 30 s):

1. the demo's 10 days simulated twice, with the heater and without it (same weather and seed),
   and the simulator's truth fluxes differenced over the heater period: where the 25 go;
2. the diagnosis's calibrated base (``search.prepare``, as ``diagnose`` builds it, seed 1) with
   its terms evaluated along both *measured* records: the heat it needs for the same warming;
3. ``p_heat`` at the injected start with the base held (the scan's two secant steps, and the
   SSE minimised exactly), refitted (``effect_fit.fit_effect_at``) and as reported (``fit_effect``
   on all data, the finding's fit);
4. the base scaled by λ (``m_cap`` and every flux coefficient): its shooting SSE and the best
   ``p_heat`` at each λ, among them the simulator's own air-node capacity over C_ter.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.series import Series
from training import demo

SCALED = ("m_cap", "c_asw", "c_cnv_ss", "c_cnd_cnv", "c_a", "c_bd", "c_bn", "c_ven_d", "c_loss",
          "c_lw_sky")
"""The structured Almería base's parameters that scale its heat balance together (the others,
``c_tsw`` and ``c_ven_w``, do not: tests/test_diagnose_units.py)."""
DAYS = demo.DAYS
SEED = 1  # the demo's


def simulate_pair(out: Path) -> dict[str, Path]:
    """The demo's run with its heater and without it, written to ``out`` (CSV + truth)."""
    from training.simulate import simulate

    paths = {}
    for name, effects in (("heater", [demo.effect_spec(DAYS)]), ("none", [])):
        r = simulate("almeria", "bleiswijk", start=demo.START, days=DAYS, effects=effects,
                     seed=SEED)
        paths[name] = out / f"{name}.csv"
        r.write(paths[name])
    return paths


def truth_split(paths: dict[str, Path]) -> list[str]:
    """Truth fluxes [W m-2 of floor] heater − none, means over the heater's minutes."""
    h, n = (np.load(paths[k].with_suffix(".truth.npz")) for k in ("heater", "none"))
    on = h["q_heater"] > 0

    def d(k: str) -> float:
        return float(np.mean(h[k][on].astype(float) - n[k][on].astype(float)))

    paths_out = {"air -> cover": d("q_conv_air_cover"), "transpiration": d("q_transpiration"),
                 "leakage": d("q_leak"), "vents": d("q_vent"),
                 "air -> floor": -d("q_conv_floor_air"), "air storage": d("s_air")}
    lines = [f"truth: q_heater {float(np.mean(h['q_heater'][on])):.3f} W m-2 on {int(on.sum())} "
             f"minutes; heater - none over them:"]
    lines += [f"  {k:14s} {v:7.2f} W m-2 ({100 * v / 25.0:3.0f} %)" for k, v in paths_out.items()]
    lines.append(f"  sum {sum(paths_out.values()):.2f}; crop sensible heat to the air "
                 f"{d('q_crop_air'):+.2f}")
    for k in ("t_air", "t_floor", "t_cover"):
        lines.append(f"  {k} {d(k):+.2f} K")
    lines.append(f"  vents open (minutes, heater/none): {int((h['vent_roof'] > 0).sum())}/"
                 f"{int((n['vent_roof'] > 0).sum())} roof, of which after the start "
                 f"{int((h['vent_roof'][on] > 0).sum())}; house loss "
                 f"{25.0 / d('t_air'):.2f} W m-2 K-1")
    return lines


def load(path: Path) -> tuple[Series, Greenhouse, object]:
    """The demo's inputs as the gateway's ``diagnose`` reads them."""
    from gateway.cli.common import load_inputs
    from training.simulate.weather import BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE

    ns = argparse.Namespace(data=str(path), greenhouse="almeria-palmerillas", model="almeria",
                            site=(BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE), step=60.0,
                            sampling="instant")
    return load_inputs(ns)


def model_terms(start, gh: Greenhouse, paths: dict[str, Path]) -> list[str]:
    """The calibrated base's terms along each measured record, heater − none."""
    from gateway.diagnose.fit import coarsen, drivers

    m0, th = start.state.model0, start.theta
    q = m0.columns(th[None])
    flux, on = {}, None
    for name in ("heater", "none"):
        c = coarsen(load(paths[name])[0], start.k)
        x = m0.prepare(drivers(c, gh))
        xi, ta = m0._inputs(q, x, slice(None)), x["t_in"][None, :]
        flux[name] = {}
        for term in m0.terms:
            g, s = term.coefficients(q, xi, ta, slice(None))
            flux[name][term.name] = np.broadcast_to(g - s * ta, ta.shape)[0]
        on = c.time >= demo.effect_start(DAYS) if on is None else on
    diff = {k: float(np.nanmean(flux["none"][k][on] - flux["heater"][k][on])) for k in flux["none"]}
    lines = ["calibrated base: " + ", ".join(f"{n} {th[m0.index(n)]:.4g}" for n in m0.names),
             f"its terms along the measured records, heat needed for the warming "
             f"{sum(diff.values()):.2f} W m-2:"]
    lines += [f"  {k:10s} {v:7.2f}" for k, v in diff.items()]
    return lines


def _best_p(shoot, theta: np.ndarray, ja: int) -> float:
    """The p_heat that minimises the shooting SSE, everything else held (Brent)."""
    from scipy.optimize import minimize_scalar

    def sse(a: float) -> float:
        t = theta.copy()
        t[ja] = a
        return float(shoot.sse(t[None])[0][0])

    return float(minimize_scalar(sse, bounds=(0.0, 200.0), method="bounded",
                                 options={"xatol": 1e-4}).x)


def fits(start, gh: Greenhouse, series: Series) -> list[str]:
    """p_heat at the injected start, base held / refitted / as reported; then the scale."""
    from gateway.diagnose.base import carry
    from gateway.diagnose.effect_fit import fit_effect, fit_effect_at
    from gateway.diagnose.effects import EFFECTS, compose
    from gateway.diagnose.fit import scan_tau
    from gateway.diagnose.structure import physical_capacity
    from gateway.model.psychrometrics import CP_AIR
    from training.simulate.integrate import RHO_AIR
    from training.simulate.plant import ALMERIA

    st, e = start.state, EFFECTS["heat_source"]
    ctx, m0, th0 = st.ctx, st.model0, start.theta
    tau = float((demo.effect_start(DAYS) - series.time[0]) / np.timedelta64(1, "s"))
    m = compose(m0, [e], gh, ctx.duration)
    ja, jt = m.index(e.amp_name), m.index(e.tau_name)
    whole = [(0, st.held.n)]
    shoot, shoot0 = ctx.shooting(m, whole), ctx.shooting(m0, whole)
    th = carry(th0, m0, m, gh)
    th[jt] = tau
    held = scan_tau(shoot, th, e, np.array([tau]), float(shoot.sse(th[None])[0][0])).amps[0]
    refit = fit_effect_at(ctx, m, m0, th0, e, whole, tau).theta
    rep = fit_effect(ctx, m, m0, th0, e, whole, latest=False).theta
    lines = [f"p_heat at the injected start: base held {held:.3f} (scan), "
             f"{_best_p(shoot, th, ja):.3f} (SSE minimised); base refitted {refit[ja]:.3f}; "
             f"reported {rep[ja]:.3f} at {(rep[jt] - tau) / 60:+.0f} min"]
    c_ter = physical_capacity(gh)
    c_sim = RHO_AIR * CP_AIR * ALMERIA.volume / ALMERIA.floor_area + ALMERIA.fast_capacity
    lines.append(f"capacity: C_ter {c_ter:.0f}, simulator's air node {c_sim:.0f} J m-2 K-1 "
                 f"({c_sim / c_ter:.3f} C_ter)")
    for lam in (0.5, 1.0, c_sim / c_ter):
        t0, t = th0.copy(), th.copy()
        for name in SCALED:
            t0[m0.index(name)] *= lam
            t[m.index(name)] *= lam
        p = _best_p(shoot, t, ja)
        lines.append(f"  λ {lam:.3f}: base SSE {float(shoot0.sse(t0[None])[0][0]):.6f}, best "
                     f"p_heat {p:.3f} = {p / lam:.3f} λ; heating rate "
                     f"{3600 * p / (lam * th0[m0.index('m_cap')] * c_ter):.2f} K h-1")
    lines.append(f"  simulator: {3600 * 25.0 / c_sim:.2f} K h-1")
    return lines


def main(argv: list[str] | None = None) -> int:
    from gateway.diagnose import search

    ap = argparse.ArgumentParser(prog="python -m training.demo_heater",
                                 description=__doc__.split("\n\n")[0].replace("``", "")
                                 .removesuffix(":") + ".")
    ap.add_argument("--out", type=demo.output_folder, default="out/demo-heater", metavar="DIR",
                    help="folder for the two runs, created with its parents (default "
                    "out/demo-heater)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    paths = simulate_pair(out)
    print("\n".join(truth_split(paths)), flush=True)
    series, gh, model = load(paths["heater"])
    start = search.prepare(series, gh, model, 0.5, SEED)
    print("\n".join(model_terms(start, gh, paths)), flush=True)
    print("\n".join(fits(start, gh, series)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Structural calibration of the base model on the calibration part (docs/effects.md, "Base
structure").

The thesis model + an effective heat capacity (+ a long-wave sky loss where it has none; + the
night sky level, a site-level night cloud fraction, when ``NIGHT_SKY_IN_BASE``) is fitted
first; then the optional parts (vents a controller opens above a setpoint, where the model
has an air-exchange term; a radiative sky loss where the model has only its own, wind-scaled
one; a heat store; a constant sensor offset) are tried in turn from the fitted base, and each
is kept only if the base extrapolates better: fitted on the first part of C, judged on its last
part (an inner validation split, not in-sample BIC alone). RSBA explores, Levenberg–Marquardt
converges, both on multiple-shooting free runs (fit.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from gateway.diagnose import night_sky
from gateway.diagnose.bic import delta_bic, effective_samples
from gateway.diagnose.fit import Shooting, fit_lm, fit_swarm, radiation_fit, window_starts
from gateway.diagnose.structure import STORE, SensorBias, SkyLoss, Structured, model_unit, structure
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model
from gateway.model.vent_control import ControlledVentilation

BASE_ITERATIONS = 80
OPTION_ITERATIONS = 40
LM_ITERATIONS = 25
INNER_SPLIT = 2.0 / 3.0
"""Share of the calibration part the structure candidates are fitted on (the rest judges)."""
MIN_VALIDATION_GAIN = 0.02
"""Relative cut of the inner validation MSE an optional part must bring to be kept."""
NIGHT_SKY_IN_BASE = False
"""Whether the base carries the night sky level (gateway/diagnose/night_sky.py): the prior the
kit's carried night cloud relaxes to replaced by a site-level cloud fraction fitted with the
base on the calibration part. Off: on the tuning generators it cut the mean effect-free base
error (refsim 0.856 → 0.742, twonode 0.668 → 0.549 K) but made two suite verdicts worse and
one better, at × 1.57 CPU (× 1.31 since the sky is computed once per shooting call); again
under the day-test judge (2026-11-27): no effect kind gained a pass, one verdict worse
(docs/effects.md, "Base structure"); together with ``WIDE_VENT_BOX`` over seeds 2 and 3
(2026-11-27): kinds passing +2, but twonode 8 of 10 effect-free windows quiet on both seeds
(docs/effects.md, "The suite's seed noise"); twonode winter's false alarm under it comes from
this switch alone: a fading held-out warm spell the kit's sky does not see, with c_loss and
c_store on bounds (docs/effects.md, "Why the freer base gives twonode winter a heater"); the
part stays available."""
OFFER_NIGHT_SKY = False
"""Whether ``options`` offers the night sky level as an optional part instead (tried after the
sky loss, kept on the inner validation split): measured, not the choice (docs/effects.md)."""
NIGHT_SKY_WIDTH: float | None = None
"""With the night sky level: the half-width of the box it is fitted in around its start (the
kit's mean prior over C's nights), a guard against a level trading with the air exchange or a
sensor offset; None: the whole 0..1. A measurement (docs/effects.md), not the choice."""
WIDE_VENT_BOX = False
"""Whether the vent controller part fits C_vc in ``VENT_BOX_UPPER`` instead of the term's
1e-3 m s-1 K-1 (about 1 air change an hour per kelvin above the setpoint in a 3.5 m house),
which caps a summer house's vents far below their physical exchange. Off: on the tuning
generators it cut the effect-free base error (refsim mean 0.856 → 0.733 K, summer 1.393 →
0.689; twonode 0.668 → 0.666) but five suite verdicts got worse and two better, all in refsim
summer (docs/effects.md, "The summer base (issue 10)"); with ``NIGHT_SKY_IN_BASE`` over seeds
2 and 3 (2026-11-27): kinds +2, twonode 8 of 10 quiet on both seeds (docs/effects.md, "The
suite's seed noise")."""
VENT_BOX_UPPER = 1e-2
"""[m s-1 K-1] C_vc's physical upper bound: a wide-open Mediterranean house exchanges ~40 h-1
(Kittas et al. 1997; Boulard & Baille 1995), reached over a proportional band of ~4 K
(Vanthoor 2011 §2.4) in a house ~3.6 m high: 40 h-1 × 3.6 m / 3600 s / 4 K = 1e-2."""
STORE_START = {"c_store": 5e4, "h_store": 3.0, "k_store": 3.0, "a_store": 0.1}
"""Where the heat store's fit starts (a floor-like store: 5 cm of wet sand, h ≈ 3 W m-2 K-1)."""

Progress = Callable[[str], None]
Resample = Callable[[np.ndarray], np.ndarray]
"""Shooting window starts in, the starts to fit on out (``calibrate_base``'s ``resample``)."""


def carry(theta: np.ndarray, old: Model, new: Model, gh: Greenhouse | None = None,
          start: dict[str, float] | None = None) -> np.ndarray:
    """Parameter vector for ``new``: values of ``old`` by name, the rest from ``start`` or at
    their defaults."""
    out = new.defaults(gh)
    for j, name in enumerate(new.names):
        if name in old.names:
            out[j] = theta[old.index(name)]
        elif start and name in start:
            out[j] = start[name]
    return out


def free_parameters(model: Model) -> list[int]:
    """Indices fitted on T_in: everything but c_tsw (fitted on i_in) and start times."""
    rad = model.radiation.parameter.name if model.radiation is not None else None
    return [j for j, nm in enumerate(model.names) if nm != rad and not nm.startswith("tau_")]


def fit(model: Model, theta: np.ndarray, shoot: Shooting, gh: Greenhouse, iterations: int,
        seed: int) -> np.ndarray:
    """RSBA (``iterations``, none: Levenberg–Marquardt only) then Levenberg–Marquardt."""
    lo, hi = model.bounds(gh)
    free = free_parameters(model)
    if iterations:
        theta = fit_swarm(shoot, theta, free, lo, hi, iterations, seed)
    return fit_lm(shoot, theta, free, lo, hi, LM_ITERATIONS)


def options(model: Structured, gh: Greenhouse) -> list[tuple[str, Callable[[Structured], Structured]]]:
    """The optional parts, in the order they are tried."""
    out: list[tuple[str, Callable[[Structured], Structured]]] = [
        ("heat store", lambda m: replace(m, store=True, extra=m.extra + STORE)),
        ("sensor offset", lambda m: m.with_sensors(SensorBias())),
    ]
    if not any(t.name == SkyLoss.name for t in model.terms):
        # The model has its own sky term (the prototype's III.21 scales it by the outside
        # convection coefficient h_o, i.e. by the wind): try the plain radiative form too,
        # before the offset, which would otherwise take up the night-time deficit as a
        # constant reading error (docs/effects.md, "Base structure").
        out.insert(0, ("long-wave sky loss",
                       lambda m: m.with_terms(SkyLoss(model_unit(m, gh)))))
    if any(t.name == "q_loss" for t in model.terms) and not any(
            t.name == ControlledVentilation.name for t in model.terms):
        # vents a climate computer opens above a setpoint, unseen by the kit: the summer
        # balance's largest unmodelled flux (docs/effects.md, "Base structure"). Only beside
        # the prototype's q_loss (III.19), whose lumped units (III.14) the term shares.
        out.insert(0, ("vent controller",
                       lambda m: m.with_terms(ControlledVentilation(
                           gh.air_density, VENT_BOX_UPPER if WIDE_VENT_BOX else None))))
    if OFFER_NIGHT_SKY and model.night_sky is None:
        # the sky's night level with the loss to it: before the store and the offset, which
        # would otherwise take up the misread nights (docs/effects.md, "Base structure")
        at = [lb for lb, _ in out].index("heat store")
        out.insert(at, ("night sky level", lambda m: m.with_night_sky()))  # full box
    return out


def night_start(x: dict, s: int) -> dict[str, float]:
    """Where the night sky level's fit starts: the mean of the prior the kit's night cloud
    relaxes to, over the calibration rows (so the part starts close to the base without it)."""
    w = x[night_sky.RELAX][:s]
    prior = float(np.sum(w * x[night_sky.PRIOR][:s]) / max(float(np.sum(w)), 1e-9))
    return {night_sky.LEVEL.name: prior}


def night_bounds(prior: float) -> tuple[float, float]:
    """The night sky level's box: 0..1, or ±``NIGHT_SKY_WIDTH`` around ``prior`` within it."""
    lo, hi = night_sky.LEVEL.lower, night_sky.LEVEL.upper
    if NIGHT_SKY_WIDTH is None:
        return lo, hi
    return max(lo, prior - NIGHT_SKY_WIDTH), min(hi, prior + NIGHT_SKY_WIDTH)


def calibrate_base(base: Model, gh: Greenhouse, x: dict, dt: float, s: int, horizon: int,
                   seed: int, say: Progress, resample: Resample | None = None
                   ) -> tuple[Structured, np.ndarray, list[dict]]:
    """Structural calibration on rows [0, s) (module docstring).

    The structure is chosen on an inner split of C: fitted on its first part C1 (the first
    ``INNER_SPLIT``), judged on the free runs of its last part C2, which the fits never saw
    and whose weather is the next regime, as the held-out part's will be. An option is kept
    when it cuts the C2 error by at least ``MIN_VALIDATION_GAIN`` (and, as before, lowers BIC
    on C1). The chosen structure is then refitted on all of C. When C is too short to split,
    the choice falls back to BIC on C.

    ``resample`` (None in the diagnosis): maps every set of shooting window starts the
    calibration uses (the fits on C1, the inner validation on C2, the refit on C) to the starts
    to use instead, a start repeated m times weighing m times (a study's bootstrap,
    tests/generality/bagged_base.py); None leaves them as they are."""
    s1 = int(round(INNER_SPLIT * s))
    inner = s1 >= 3 * horizon and s - s1 >= 2 * horizon
    fit_seg = [(0, s1)] if inner else [(0, s)]
    pick = resample or (lambda st: st)
    starts = pick(window_starts(fit_seg, horizon, skip=horizon))
    val_starts = pick(window_starts([(s1, s)], horizon)) if inner else np.zeros(0, dtype=int)
    model = structure(base, gh, store=False)
    start = STORE_START | night_start(x, s)
    if NIGHT_SKY_IN_BASE:
        model = model.with_night_sky(*night_bounds(start[night_sky.LEVEL.name]))
    theta = model.defaults(gh)
    if model.night_sky is not None:
        theta[model.index(night_sky.LEVEL.name)] = start[night_sky.LEVEL.name]
    theta = radiation_fit(model, x, theta, (0, s))
    say("calibrating the base model (thesis terms + effective heat capacity)")
    shoot = Shooting(model, x, gh, dt, starts, horizon)
    theta = fit(model, theta, shoot, gh, BASE_ITERATIONS, seed)
    sse, npair = shoot.sse(theta[None])
    val = _validation(model, theta, x, gh, dt, val_starts, horizon)
    log = [{"structure": "base", "detail": structure_detail(model), "kept": True,
            "mse": float(sse[0] / npair), "delta_bic": 0.0, "validation_mse": val}]
    for label, build in options(model, gh):
        new = build(model)
        say(f"calibrating the base model: trying a {label}")
        th = carry(theta, model, new, gh, start)
        sh = Shooting(new, x, gh, dt, starts, horizon)
        th = fit(new, th, sh, gh, OPTION_ITERATIONS, seed + 1)
        sse_new, _ = sh.sse(th[None])
        k_new = len(new.names) - len(model.names)
        dbic = delta_bic(float(sse_new[0]), float(sse[0]), effective_samples(npair, dt), k_new)
        val_new = _validation(new, th, x, gh, dt, val_starts, horizon)
        kept = dbic < 0 and (not inner or _validated(val_new, val))
        log.append({"structure": label, "detail": structure_detail(new), "kept": bool(kept),
                    "mse": float(sse_new[0] / npair), "delta_bic": dbic, "validation_mse": val_new})
        if kept:
            model, theta, sse, val = new, th, sse_new, val_new
    if inner:  # the chosen structure, refitted on all of C
        say("calibrating the base model: the chosen structure on the whole calibration part")
        whole = pick(window_starts([(0, s)], horizon, skip=horizon))
        shoot = Shooting(model, x, gh, dt, whole, horizon)
        theta = fit(model, theta, shoot, gh, 0, seed)
    return model, theta, log


def _validated(new: float | None, old: float | None) -> bool:
    """Does ``new`` beat ``old`` by ``MIN_VALIDATION_GAIN`` on the inner validation windows?"""
    if new is None or old is None:
        raise ValueError("inner validation without validation windows")
    return new < (1.0 - MIN_VALIDATION_GAIN) * old


def _validation(model: Structured, theta: np.ndarray, x: dict, gh: Greenhouse, dt: float,
                starts: np.ndarray, horizon: int) -> float | None:
    """Shooting MSE on the inner validation windows (None without them)."""
    if len(starts) == 0:
        return None
    return float(Shooting(model, x, gh, dt, starts, horizon).mse(theta[None])[0])


def structure_detail(model: Structured) -> str:
    """The base structure's parts, for the structure log (effective heat capacity first)."""
    parts = ["effective heat capacity m_cap"]
    if any(t.name == ControlledVentilation.name for t in model.terms):
        parts.append("vent controller (c_vc, t_vc)")
    if any(t.name == "q_lw_sky" for t in model.terms):
        parts.append("long-wave sky loss c_lw_sky")
    if model.night_sky is not None:
        parts.append(f"night sky level {night_sky.LEVEL.name}")
    if model.store:
        parts.append("heat store (c_store, h_store, k_store, a_store)")
    if any(sn.name == "e_sensor_bias" for sn in model.sensors):
        parts.append("constant sensor offset b_sensor")
    return ", ".join(parts)

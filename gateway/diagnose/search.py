"""The add-best-effect loop (issue 4): calibrate, rank effects, refit, judge on held-out data.

Protocol (docs/effects.md, "How the diagnosis decides"):

1. Fits run on a grid of at least ``FIT_STEP_S`` (T_in readings, block-mean inputs); the
   reported metrics are on the data's own grid.
2. Structural calibration of the base on the first ``split`` of the data (C) only
   (structure.py): the thesis model + an effective heat capacity (+ a long-wave sky loss where it
   has none), then a radiative sky loss (where the model has only its own, wind-scaled one), a
   heat store and a constant sensor offset, each kept only if BIC on C falls.
   RSBA explores, Levenberg–Marquardt converges, both on multiple-shooting free runs.
3. The rest (H) is cut into blocks (one day, or a quarter of H when shorter) dealt into two
   folds. An effect that starts inside H can only be fitted on data that contains it, so each
   fold's judge blocks are predicted by a model whose effect (τ, amplitude) and refitted base
   parameters saw C plus the *other* fold only (two-fold blocked cross-fitting): every held-out
   figure comes from data its fit never saw, wherever the effect starts.
4. Candidates are ranked on all data by ΔBIC of their τ scan; the best ones are tried in turn:
   τ re-scanned and the base refitted jointly per fold; a τ inside C must be borne out by C
   alone (the effect as fitted, refitted on C: ΔBIC < 0), else τ is re-scanned within H. One
   is kept only if BIC falls on its fit sets AND the held-out free-run error falls
   significantly (relative MAE ≥ ``MIN_GAIN`` and a block-paired t ≥ ``MIN_T`` or an MSE
   cut ≥ ``STRONG_GAIN``). Among the candidates that pass in a round,
   the one with the lowest held-out free-run MSE wins. Repeat until nothing passes.
5. Held-out free-run error is measured by free runs restarted at each block start, for the
   model before and after alike (headline: free-run MAE), beside persistence.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from gateway.diagnose import residuals as res
from gateway.diagnose.effects import LIBRARY, Effect, compose
from gateway.diagnose.fit import (
    HORIZON_S,
    Scan,
    Shooting,
    coarsen,
    drivers,
    fit_lm,
    fit_swarm,
    measures_radiation,
    radiation_bic_delta,
    radiation_change,
    radiation_fit,
    scan_tau,
    window_starts,
)
from gateway.diagnose.humidity import exchange_step_bic
from gateway.diagnose.structure import (
    STORE,
    SensorBias,
    SkyLoss,
    Structured,
    model_unit,
    structure,
)
from gateway.greenhouse import Greenhouse
from gateway.metrics import metrics
from gateway.model.model import Model
from gateway.series import Series

FIT_STEP_S = 300.0
"""Coarsest grid the fits run on [s] (finer data is coarsened, see fit.coarsen)."""
EFFECTIVE_S = 3600.0
"""One effective sample per hour of residual in BIC: free-run residuals are autocorrelated."""
MIN_GAIN = 0.05
"""Smallest relative cut of held-out free-run MAE that can count as an improvement."""
MIN_T = 1.0
"""Block-paired t statistic of the MSE cut required (unless the cut is ≥ STRONG_GAIN)."""
STRONG_GAIN = 0.25
BLOCK_S = 12 * 3600.0
"""Length of the held-out blocks dealt into the two folds [s] (``heldout_blocks``)."""
JUDGE_PIECE_S = 6 * 3600.0
"""Length of the held-out pieces whose paired MSE differences the t statistic is taken over."""
MAX_EFFECTS = 3
TRIES_PER_ROUND = 3
BASE_ITERATIONS = 80
OPTION_ITERATIONS = 40
LM_ITERATIONS = 25
REFIT_LM_ITERATIONS = 12
COARSE_TAU_S = 3 * 3600.0
"""Spacing of the coarse grid of candidate start times [s]; refined to COARSE/36 around the best."""
STORE_START = {"c_store": 5e4, "h_store": 3.0, "k_store": 3.0, "a_store": 0.1}
"""Where the heat store's fit starts (a floor-like store: 5 cm of wet sand, h ≈ 3 W m-2 K-1)."""

Progress = Callable[[str], None]


@dataclass
class Finding:
    """One accepted effect with its fitted parameters and the evidence for it."""

    effect: Effect
    tau: float  # [s since the first sample]
    start: str | None  # ISO UTC, None = before the data
    amplitude: float
    summary: str
    evidence: str
    mae_before: float
    mae_after: float
    delta_bic: float
    trace: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """The fitted effect over the record: flux [W m-2 of floor], factor [-] or offset [K]."""
    trace_unit: str = ""

    def to_json(self) -> dict:
        e = self.effect
        return {
            "effect": e.name,
            "start": self.start,
            "params": {e.amp_name: self.amplitude, "unit": e.unit},
            "summary": self.summary,
            "evidence": self.evidence,
        }


@dataclass
class Diagnosis:
    """Everything the report and the JSON need."""

    model: Model  # final composed model
    theta: np.ndarray  # final parameters fitted on all data (for plots and findings)
    base_model: Model
    base_theta: np.ndarray
    findings: list[Finding]
    rejected: list[dict]
    before: dict
    after: dict
    persistence: dict
    unexplained: bool
    signature: str
    split_index: int
    blocks: list[tuple[int, int]]
    time: np.ndarray
    measured: np.ndarray
    pred_before: dict[str, np.ndarray]  # "free_run", "one_step" over the held-out part
    pred_after: dict[str, np.ndarray]
    analysis_before: dict = field(default_factory=dict)
    analysis_after: dict = field(default_factory=dict)
    seconds: float = 0.0
    structure: list[dict] = field(default_factory=list)
    """The base structure choices on the calibration part (step 2), in order tried."""


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


def heldout_blocks(split: int, n: int, dt: float) -> list[tuple[int, int]]:
    """The held-out part cut into blocks of ``BLOCK_S`` (a quarter of it when shorter).

    Half a day: long enough for a free run to forget its measured start (the air and fast
    mass relax within an hour or two), short enough that each fold's fit set samples the whole
    held-out part densely, so an effect growing in time (a drift) is pinned down on both sides
    of every judged block."""
    length = n - split
    want = int(round(BLOCK_S / dt))
    block = want if length >= 4 * want else max(length // 4, 2)
    edges = list(range(split, n, block))
    blocks = [(a, min(a + block, n)) for a in edges]
    if len(blocks) > 1 and blocks[-1][1] - blocks[-1][0] < block // 2:
        a, _ = blocks.pop()
        blocks[-1] = (blocks[-1][0], n)
    return blocks


def _free(model: Model) -> list[int]:
    """Indices fitted on T_in: everything but c_tsw (fitted on i_in) and start times."""
    rad = model.radiation.parameter.name if model.radiation is not None else None
    return [j for j, nm in enumerate(model.names) if nm != rad and not nm.startswith("tau_")]


def _bic_delta(sse_new: float, sse_old: float, n_pairs: int, dt: float, k_new: int) -> float:
    """ΔBIC = n_e ln(SSE_new/SSE_old) + k ln(n_e) with n_e = one effective sample per
    ``EFFECTIVE_S`` of compared residuals."""
    n_e = max(n_pairs * dt / EFFECTIVE_S, 2.0)
    return float(n_e * np.log(max(sse_new, 1e-300) / max(sse_old, 1e-300)) + k_new * np.log(n_e))


def _fit(model: Model, theta: np.ndarray, shoot: Shooting, gh: Greenhouse, iterations: int,
         seed: int) -> np.ndarray:
    lo, hi = model.bounds(gh)
    free = _free(model)
    if iterations:
        theta = fit_swarm(shoot, theta, free, lo, hi, iterations, seed)
    return fit_lm(shoot, theta, free, lo, hi, LM_ITERATIONS)


def calibrate_base(base: Model, gh: Greenhouse, x: dict, dt: float, s: int, horizon: int,
                   seed: int, say: Progress) -> tuple[Structured, np.ndarray, list[dict]]:
    """Structural calibration on rows [0, s) (module docstring, step 2)."""
    starts = window_starts([(0, s)], horizon, skip=horizon)
    model = structure(base, gh, store=False)
    theta = radiation_fit(model, x, model.defaults(gh), (0, s))
    say("calibrating the base model (thesis terms + effective heat capacity)")
    shoot = Shooting(model, x, gh, dt, starts, horizon)
    theta = _fit(model, theta, shoot, gh, BASE_ITERATIONS, seed)
    sse, npair = shoot.sse(theta[None])
    log = [{"structure": "base", "detail": _structure_detail(model), "kept": True,
            "mse": float(sse[0] / npair), "delta_bic": 0.0}]
    options = [
        ("heat store", lambda m: replace(m, store=True, extra=m.extra + STORE)),
        ("sensor offset", lambda m: m.with_sensors(SensorBias())),
    ]
    if not any(t.name == SkyLoss.name for t in model.terms):
        # The model has its own sky term (the prototype's III.21 scales it by the outside
        # convection coefficient h_o, i.e. by the wind): try the plain radiative form too,
        # before the offset, which would otherwise take up the night-time deficit as a
        # constant reading error (docs/effects.md, "Base structure").
        options.insert(0, ("long-wave sky loss", lambda m: m.with_terms(SkyLoss(model_unit(m, gh)))))
    for label, build in options:
        new = build(model)
        say(f"calibrating the base model: trying a {label}")
        th = carry(theta, model, new, gh, STORE_START)
        sh = Shooting(new, x, gh, dt, starts, horizon)
        th = _fit(new, th, sh, gh, OPTION_ITERATIONS, seed + 1)
        sse_new, _ = sh.sse(th[None])
        k_new = len(new.names) - len(model.names)
        dbic = _bic_delta(float(sse_new[0]), float(sse[0]), npair, dt, k_new)
        kept = dbic < 0
        log.append({"structure": label, "detail": _structure_detail(new), "kept": bool(kept),
                    "mse": float(sse_new[0] / npair), "delta_bic": dbic})
        if kept:
            model, theta, sse = new, th, sse_new
    return model, theta, log


def _structure_detail(model: Structured) -> str:
    parts = ["effective heat capacity m_cap"]
    if any(t.name == "q_lw_sky" for t in model.terms):
        parts.append("long-wave sky loss c_lw_sky")
    if model.store:
        parts.append("heat store (c_store, h_store, k_store, a_store)")
    if any(sn.name == "e_sensor_bias" for sn in model.sensors):
        parts.append("constant sensor offset b_sensor")
    return ", ".join(parts)


def diagnose(
    series: Series,
    gh: Greenhouse,
    base: Model,
    split: float = 0.5,
    seed: int = 0,
    library: tuple[Effect, ...] = LIBRARY,
    progress: Progress | None = None,
) -> Diagnosis:
    """Run the whole diagnosis on ``series`` (see the module docstring)."""
    t_start = _time.perf_counter()
    say = progress or (lambda msg: None)
    if not 0.1 <= split <= 0.9:
        raise ValueError(f"split must be within [0.1, 0.9], got {split}")
    k = max(int(FIT_STEP_S // series.step), 1)
    coarse = coarsen(series, k)
    n, dt = len(coarse), coarse.step
    s = int(round(split * n))
    horizon = max(int(round(HORIZON_S / dt)), 2)
    if s < 3 * horizon or n - s < 2 * horizon:  # before drivers(): it needs a first row
        raise ValueError(
            f"{series.source}: {len(series)} samples of {series.step:g} s are too few to "
            f"diagnose: the calibration part needs at least {3 * HORIZON_S / 3600:g} h and "
            f"the held-out part {2 * HORIZON_S / 3600:g} h"
        )
    x = drivers(coarse, gh)
    duration = float(x["_index"][-1])
    blocks = heldout_blocks(s, n, dt)
    folds = [[b for i, b in enumerate(blocks) if i % 2 == j] for j in (0, 1)]
    fit_sets = [[(0, s)] + folds[1 - j] for j in (0, 1)]  # fold j is judged on folds[j]

    # 1. structural calibration on C
    model0, theta, structure_log = calibrate_base(base, gh, x, dt, s, horizon, seed, say)
    base_theta = theta.copy()

    model = model0
    thetas = [theta.copy(), theta.copy()]  # per fold
    theta_all = theta.copy()
    before_pred = _heldout(model, thetas, x, gh, dt, folds, s, n)
    findings: list[Finding] = []
    rejected: list[dict] = []
    effects: list[Effect] = []
    current_pred = before_pred
    all_set = [(0, n)]

    for rnd in range(1, MAX_EFFECTS + 1):
        candidates = [e for e in library if e not in effects]
        if not candidates:
            break
        say(f"round {rnd}: ranking {len(candidates)} candidate effects")
        ranked = _rank(model0, model, theta_all, effects, candidates, x, gh, dt, duration,
                       horizon, all_set)
        passed = []
        for scan_all, dbic_all in ranked[:TRIES_PER_ROUND]:
            if dbic_all >= 0:
                break
            e = scan_all.effect
            say(f"round {rnd}: trying {e.name}")
            new_model = compose(model0, effects + [e], gh, duration)
            new_thetas, dbics = [], []
            for j in (0, 1):
                th, dbic = _fit_effect(new_model, model, thetas[j], e, x, gh, dt, duration,
                                       horizon, fit_sets[j], seed + 17 * j, s)
                new_thetas.append(th)
                dbics.append(dbic)
            pred = _heldout(new_model, new_thetas, x, gh, dt, folds, s, n)
            verdict = _judge(current_pred, pred, x["t_in"], blocks, s, dt)
            verdict["delta_bic"] = [float(v) for v in dbics]
            # second output, independent of the T_in folds: counted once, on all data
            verdict["humidity"] = _humidity_evidence(e, x, all_set, float(scan_all.taus[scan_all.best]),
                                                     float(scan_all.amps[scan_all.best]))
            if max(dbics) < 0 and verdict["ok"]:
                passed.append((verdict["mae_after"], e, new_model, new_thetas, pred, verdict))
            else:
                rejected.append({"effect": e.name, "reason": verdict["why"], "delta_bic": dbics})
        if not passed:
            break
        # One score per passing candidate, all parts log-likelihood ratios with one
        # effective sample per EFFECTIVE_S: the evidence of its fits (ΔBIC summed over both
        # folds' fit sets), the night-time humidity evidence on all data (extra_ventilation
        # only, humidity.py), plus its held-out free-run MSE against the best one's. A rival the
        # held-out part barely separates is decided by the fits, and the other way round.
        best_mse = min(c[5]["mse_after"] for c in passed)
        n_h = np.isfinite(x["t_in"][s:]).sum() * dt / EFFECTIVE_S

        def score(c, n_h=n_h, best_mse=best_mse) -> float:
            return (sum(c[5]["delta_bic"]) + c[5]["humidity"]
                    + n_h * np.log(c[5]["mse_after"] / best_mse))

        passed.sort(key=score)
        _, e, new_model, new_thetas, pred, verdict = passed[0]
        for other in passed[1:]:
            rejected.append({"effect": other[1].name, "reason": "passed, but a rival has "
                             f"more evidence (score {score(other):.0f} vs {score(passed[0]):.0f},"
                             " fit ΔBIC + humidity + held-out): " + other[5]["why"],
                             "delta_bic": other[5]["delta_bic"]})
        th_all, dbic_full = _fit_effect(new_model, model, theta_all, e, x, gh, dt, duration,
                                        horizon, all_set, seed + 101, s)
        findings.append(_finding(e, new_model, th_all, series, current_pred, pred, verdict,
                                 dbic_full, x, s))
        effects.append(e)
        model, thetas, theta_all, current_pred = new_model, new_thetas, th_all, pred
        say(f"kept {e.name}: {findings[-1].summary}")

    # 2. figures on the data's own grid
    xf = drivers(series, gh)
    nf, dtf = len(series), series.step
    sf = s * k
    fblocks = [(a * k, b * k if b < n else nf) for a, b in blocks]
    ffolds = [[(a * k, b * k if b < n else nf) for a, b in f] for f in folds]
    before_f = _heldout(model0, [base_theta, base_theta], xf, gh, dtf, ffolds, sf, nf)
    after_f = _heldout(model, thetas, xf, gh, dtf, ffolds, sf, nf)
    meas = xf["t_in"]
    _traces(findings, model, theta_all, xf, gh)
    before = _metrics(meas, before_f, sf)
    after = _metrics(meas, after_f, sf)
    pers = _metrics(meas, _persistence(meas, fblocks, sf, nf), sf)
    an_before = res.analyse(series.time[sf:], meas[sf:] - before_f["free_run"], xf, sf, dtf)
    an_after = res.analyse(series.time[sf:], meas[sf:] - after_f["free_run"], xf, sf, dtf)
    calib_r = _calibration_free_run(model, theta_all, xf, gh, dtf, sf)
    unexplained, signature = res.unexplained(an_after, calib_r, series.time, sf)
    return Diagnosis(
        model=model, theta=theta_all, base_model=model0, base_theta=base_theta,
        findings=findings, rejected=rejected, before=before, after=after, persistence=pers,
        unexplained=unexplained, signature=signature, split_index=sf, blocks=fblocks,
        time=series.time, measured=meas, pred_before=before_f, pred_after=after_f,
        analysis_before=an_before, analysis_after=an_after,
        seconds=_time.perf_counter() - t_start, structure=structure_log,
    )


def _traces(findings: list[Finding], model: Structured, theta: np.ndarray, x, gh: Greenhouse) -> None:
    """Each finding over the record: flux (physical W m-2), factor (-) or sensor offset (K)."""
    from gateway.diagnose.structure import model_unit

    unit = model_unit(model, gh)
    n = len(x["t_in"])
    fluxes = model.fluxes(theta, x, x["t_in"])
    p = {k: v[:, 0] for k, v in model.columns(theta[None, :]).items()}
    for f in findings:
        if f.effect.kind == "sensor":
            term = next(t for t in model.sensors if t.name == "e_" + f.effect.name)
            f.trace = np.broadcast_to(term.offset(p, x, slice(0, n)), (n,)).copy()
            f.trace_unit = "K"
        elif f.effect.kind == "modulation":
            m = next(m for m in model.modulations if m.name == f.effect.name)
            f.trace = np.broadcast_to(m.factor(p, x, slice(0, n)), (n,)).copy()
            f.trace_unit = "factor"
        else:
            f.trace = fluxes["q_" + f.effect.name] / unit
            f.trace_unit = "W m-2"


# -- steps -------------------------------------------------------------------------------------
def _tau_grid(effect: Effect, duration: float, earliest: float = 0.0) -> np.ndarray:
    first = 0.0 if effect.from_start else COARSE_TAU_S
    if earliest > first:
        return np.arange(earliest, duration, COARSE_TAU_S)
    return np.arange(first, duration, COARSE_TAU_S)


def _scan(shoot: Shooting, theta: np.ndarray, e: Effect, duration: float,
          segments: list[tuple[int, int]], earliest: float = 0.0) -> Scan:
    """Coarse τ grid, then a fine grid around the best coarse τ, every τ ≥ ``earliest``. A
    cover transmission change is taken from the measured inside radiation when there is one
    (fit.radiation_change)."""
    m = shoot.model
    if e.name == "solar_gain_change" and measures_radiation(m, shoot.x):
        first = max(0.0 if e.from_start else COARSE_TAU_S, earliest)
        tau, d = radiation_change(m, shoot.x, theta, segments, first)
        th = theta.copy()
        th[m.index(e.tau_name)], th[m.index(e.amp_name)] = tau, np.clip(d, e.lower, e.upper)
        sse, npair = shoot.sse(th[None, :])
        return Scan(e, np.array([tau]), np.array([th[m.index(e.amp_name)]]), sse, npair)
    sse0, npair = shoot.sse(theta[None, :])
    # SSE differences below one effective sample's share do not tell start times apart
    rel = 1.0 / max(npair * shoot.dt / EFFECTIVE_S, 1.0)
    coarse = scan_tau(shoot, theta, e, _tau_grid(e, duration, earliest),
                      float(sse0[0])).latest_of_best(rel)
    t_best = coarse.taus[coarse.best]
    lo = max(0.0 if e.from_start else shoot.dt, earliest)
    fine_taus = np.unique(np.clip(t_best + np.linspace(-1, 1, 37) * COARSE_TAU_S, lo, duration))
    fine = scan_tau(shoot, theta, e, fine_taus, float(sse0[0])).latest_of_best(rel)
    return fine if fine.sse[fine.best] <= coarse.sse[coarse.best] * (1.0 + rel) else coarse


def _rank(base, model, theta, effects, candidates, x, gh, dt, duration, horizon, segments):
    """Each candidate's τ scan (other parameters held) on ``segments``, sorted by ΔBIC."""
    out = []
    starts = window_starts(segments, horizon, skip=horizon)
    for e in candidates:
        new = compose(base, effects + [e], gh, duration)
        th = carry(theta, model, new, gh)
        shoot = Shooting(new, x, gh, dt, starts, horizon)
        sse0, npair = shoot.sse(th[None, :])
        sc = _scan(shoot, th, e, duration, segments)
        dbic = _bic_delta(sc.sse[sc.best], float(sse0[0]), npair, dt, 2)
        out.append((sc, dbic + _radiation_evidence(new, e, x, th, segments, sc)
                    + _humidity_evidence(e, x, segments, float(sc.taus[sc.best]),
                                         float(sc.amps[sc.best]))))
    out.sort(key=lambda item: item[1])
    return out


def _fit_effect(new_model, old_model, theta_old, e, x, gh, dt, duration, horizon, segments, seed,
                split):
    """τ scan then a joint refit (base parameters + amplitude, τ held) on ``segments``.

    A start inside the calibration part (rows before ``split``) must be borne out by the
    calibration part alone (``_calibration_supports``); otherwise τ is re-scanned within the
    held-out part."""
    th = carry(theta_old, old_model, new_model, gh)
    starts = window_starts(segments, horizon, skip=horizon)
    shoot = Shooting(new_model, x, gh, dt, starts, horizon)
    sse_old, npair = shoot.sse(th[None, :])
    sc = _scan(shoot, th, e, duration, segments)
    t_split = float(x["_index"][split])
    if sc.taus[sc.best] < t_split and not _calibration_supports(
            new_model, old_model, theta_old, e, sc, x, gh, dt, horizon, split):
        sc = _scan(shoot, th, e, duration, segments, earliest=t_split)
    th[new_model.index(e.tau_name)] = sc.taus[sc.best]
    th[new_model.index(e.amp_name)] = sc.amps[sc.best]
    lo, hi = new_model.bounds(gh)
    free = _free(new_model)
    if e.name == "solar_gain_change" and measures_radiation(new_model, x):
        free = [j for j in free if new_model.names[j] != e.amp_name]  # fixed by i_in
    th = fit_lm(shoot, th, free, lo, hi, REFIT_LM_ITERATIONS)
    sse_new, _ = shoot.sse(th[None, :])
    dbic = _bic_delta(float(sse_new[0]), float(sse_old[0]), npair, dt, 2)
    return th, dbic + _radiation_evidence(new_model, e, x, th, segments, sc)


def _calibration_supports(new_model, old_model, theta_old, e: Effect, sc: Scan, x, gh, dt,
                          horizon, split) -> bool:
    """Does the calibration part C (rows before ``split``) by itself bear out the effect from
    the scanned τ (inside C)? The model without and the model with the effect (τ and amplitude
    held as the fit set found them) are both refitted on C alone (Levenberg–Marquardt, base
    parameters only): the effect is supported if ΔBIC < 0 on C.

    The base was calibrated on C; a start late in C can otherwise stand in for the base's
    extrapolation error on the held-out part (another weather regime), the effect's own data
    being mostly after the split. An effect that really began in C, with the size the rest of
    the data gives it, shows in C's tail. The amplitude is held: C's tail alone could be fitted
    by a much larger step of the same sign (a local deviation), which is not the same effect."""
    seg = [(0, split)]
    starts = window_starts(seg, horizon, skip=horizon)
    if len(starts) == 0:
        return False
    sh_old = Shooting(old_model, x, gh, dt, starts, horizon)
    lo, hi = old_model.bounds(gh)
    th_old = fit_lm(sh_old, theta_old.copy(), _free(old_model), lo, hi, REFIT_LM_ITERATIONS)
    sse_old, npair = sh_old.sse(th_old[None, :])
    th = carry(th_old, old_model, new_model, gh)
    ja = new_model.index(e.amp_name)
    th[new_model.index(e.tau_name)] = sc.taus[sc.best]
    th[ja] = sc.amps[sc.best]
    sh_new = Shooting(new_model, x, gh, dt, starts, horizon)
    lo, hi = new_model.bounds(gh)
    free = [j for j in _free(new_model) if j != ja]
    th = fit_lm(sh_new, th, free, lo, hi, REFIT_LM_ITERATIONS)
    sse_new, _ = sh_new.sse(th[None, :])
    dbic = _bic_delta(float(sse_new[0]), float(sse_old[0]), npair, dt, 2)
    dbic += _radiation_evidence(new_model, e, x, th, seg, sc)
    return bool(dbic < 0 and th[ja] != e.neutral)


def _radiation_evidence(model, e: Effect, x, theta, segments, sc: Scan) -> float:
    """The inside-radiation part of ΔBIC for a transmission change when i_in is measured
    (the change is fitted on it, fit.radiation_change); 0 for every other effect."""
    if e.name != "solar_gain_change" or not measures_radiation(model, x):
        return 0.0
    return radiation_bic_delta(model, x, theta, segments, float(sc.taus[sc.best]),
                               float(sc.amps[sc.best]), EFFECTIVE_S)


def _humidity_evidence(e: Effect, x, segments, tau: float, amp: float) -> float:
    """The vapour-balance part of ΔBIC for added air exchange (humidity.exchange_step_bic):
    more exchange from τ dilutes the night-time vapour excess, a solar change does not. Only
    for ``extra_ventilation`` with a positive fitted rate (n = 0 predicts no change) and only
    when τ is inside the data; 0 without humidity readings."""
    if e.name != "extra_ventilation" or amp <= 0.0 or tau <= 0.0:
        return 0.0
    return exchange_step_bic(x, segments, tau)[0]


def _heldout(model, thetas, x, gh, dt, folds, s, n) -> dict[str, np.ndarray]:
    """Cross-fitted held-out predictions: free runs restarted at each block start, one-step."""
    free = np.full(n - s, np.nan)
    one = np.full(n - s, np.nan)
    for j in (0, 1):
        th = thetas[j][None, :]
        if not folds[j]:
            continue
        o = model.one_step(th, x, gh, dt)[0]
        for a, b in folds[j]:
            free[a - s : b - s] = model.free_run(th, x, gh, dt, start=a, stop=b)[0]
            one[a - s : b - s] = o[a:b]
    return {"free_run": free, "one_step": one}


def _persistence(meas, blocks, s, n) -> dict[str, np.ndarray]:
    """Naive baselines: the previous reading (one-step), the block's first reading (free run)."""
    free = np.full(n - s, np.nan)
    for a, b in blocks:
        free[a - s : b - s] = meas[a]
    one = np.concatenate([[np.nan], meas[s:-1]])
    return {"free_run": free, "one_step": one}


def _metrics(meas, pred, s) -> dict:
    m = meas[s:]
    return {k: metrics(m, v) for k, v in pred.items()}


def _judge(before, after, meas, blocks, s, dt) -> dict:
    """Is the held-out free-run error significantly lower after? The paired t statistic is
    over pieces of ``JUDGE_PIECE_S`` of the blocks (free-run residuals decorrelate within
    hours; whole blocks would leave only a handful of pairs)."""
    eb = (before["free_run"] - meas[s:]) ** 2
    ea = (after["free_run"] - meas[s:]) ** 2
    ok = np.isfinite(eb) & np.isfinite(ea)
    piece = max(int(round(JUDGE_PIECE_S / dt)), 1)
    d = []
    for a0, b0 in blocks:
        for a in range(a0, b0, piece):
            b = min(a + piece, b0)
            k = ok[a - s : b - s]
            if k.any():
                d.append(np.mean(eb[a - s : b - s][k]) - np.mean(ea[a - s : b - s][k]))
    d = np.array(d)
    mae_b = float(np.mean(np.sqrt(eb[ok])))
    mae_a = float(np.mean(np.sqrt(ea[ok])))
    mse_b, mse_a = float(np.mean(eb[ok])), float(np.mean(ea[ok]))
    gain = 1.0 - mae_a / mae_b if mae_b > 0 else 0.0
    mse_gain = 1.0 - mse_a / mse_b if mse_b > 0 else 0.0
    sd = float(np.std(d, ddof=1)) if len(d) > 1 else float("inf")
    t = float(np.mean(d) / (sd / np.sqrt(len(d)))) if sd > 0 else (np.inf if np.mean(d) > 0 else 0.0)
    good = gain >= MIN_GAIN and (t >= MIN_T or mse_gain >= STRONG_GAIN)
    why = (f"held-out free-run MAE {mae_b:.3f} → {mae_a:.3f} °C ({-100 * gain:+.0f} %), "
           f"paired t = {t:.2f} over {len(d)} pieces of {JUDGE_PIECE_S / 3600:g} h")
    return {"ok": bool(good), "why": why, "gain": gain, "t": t, "mae_before": mae_b,
            "mae_after": mae_a, "mse_after": mse_a}


def _calibration_free_run(model, theta, x, gh, dt, s) -> np.ndarray:
    """In-sample free-run residual on the calibration part (blocks of one day), for comparison."""
    day = int(round(86400.0 / dt))
    block = min(day, max(s // 2, 2))
    errs = []
    for a in range(0, s - 1, block):
        b = min(a + block, s)
        if b - a < 2:
            continue
        pred = model.free_run(theta[None, :], x, gh, dt, start=a, stop=b)[0]
        errs.append(x["t_in"][a:b] - pred)
    return np.concatenate(errs)


def _finding(e, model, theta, series, pred_before, pred_after, verdict, dbic, x, s):
    tau = float(theta[model.index(e.tau_name)])
    amp = float(theta[model.index(e.amp_name)])
    stamp = series.time[0] + np.timedelta64(int(round(tau)), "s")
    start = None if tau <= 0 else str(stamp) + "Z"
    when = f"from {str(stamp)[:16].replace('T', ' ')} UTC" if start else "throughout the data"
    summary = f"{e.describe(amp)} {when}"
    r = x["t_in"][s:] - pred_before["free_run"]
    t_c = series.time[0] + x["_index"].astype("timedelta64[s]")
    sig = res.short_signature(t_c[s:], r, x, s, float(x["_index"][1] - x["_index"][0]))
    evidence = (f"{verdict['why']}; ΔBIC {dbic:.0f} on all data; residual before it: {sig}; "
                f"expected signature: {e.signature}")
    return Finding(e, tau, start, amp, summary, evidence, verdict["mae_before"],
                   verdict["mae_after"], dbic)


def to_json(d: Diagnosis) -> dict:
    """The ``--json`` object: findings, before/after held-out metrics, unexplained."""
    def strip(m: dict) -> dict:
        return {k: (None if v is None else {q: v[q] for q in ("mae", "rmse", "maxae", "r2", "ef")})
                for k, v in m.items()}

    return {
        "findings": [f.to_json() for f in d.findings],
        "before": strip(d.before),
        "after": strip(d.after),
        "persistence": strip(d.persistence),
        "unexplained": d.unexplained,
        "signature": d.signature,
        "base_structure": d.structure,
        "rejected": d.rejected,
        "heldout": {"start": str(d.time[d.split_index]) + "Z", "end": str(d.time[-1]) + "Z",
                    "blocks": len(d.blocks)},
        "seconds": d.seconds,
    }

"""The add-best-effect loop (issue 4): calibrate, rank effects, refit, judge on held-out data.

Protocol (docs/effects.md, "How the diagnosis decides"):

1. The base model is calibrated on the first ``split`` of the data (C) only.
2. The rest (H) is cut into blocks (one day, or a quarter of H when shorter) dealt into two
   folds. An effect that starts inside H can only be fitted on data that contains it, so each
   fold's judge blocks are predicted by a model whose effect (τ, amplitude) and refitted base
   parameters saw C plus the *other* fold only (two-fold blocked cross-fitting): every held-out
   figure comes from data its fit never saw, wherever the effect starts.
3. Candidates are ranked by the drop of the multiple-shooting SSE over all data (BIC with one
   effective sample per ``HORIZON_S`` window); the best is added, its τ re-scanned and the base
   refitted jointly per fold. It is kept only if BIC falls on its fit sets AND the held-out
   free-run error falls significantly (relative MAE ≥ ``MIN_GAIN`` and a block-paired t ≥
   ``MIN_T`` or an MSE cut ≥ ``STRONG_GAIN``). Repeat until nothing passes.
4. Held-out free-run error is measured by free runs restarted at each block start, for the
   model before and after alike (headline: free-run MAE), beside persistence.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gateway.diagnose import residuals as res
from gateway.diagnose.effects import LIBRARY, Effect
from gateway.diagnose.fit import (
    HORIZON_S,
    Scan,
    Shooting,
    drivers,
    fit_swarm,
    radiation_fit,
    scan_tau,
    window_starts,
)
from gateway.greenhouse import Greenhouse
from gateway.metrics import metrics
from gateway.model.model import Model
from gateway.series import Series

MIN_GAIN = 0.05
"""Smallest relative cut of held-out free-run MAE that can count as an improvement."""
MIN_T = 1.0
"""Block-paired t statistic of the MSE cut required (unless the cut is ≥ STRONG_GAIN)."""
STRONG_GAIN = 0.25
MAX_EFFECTS = 3
TRIES_PER_ROUND = 2
BASE_ITERATIONS = 120
REFIT_ITERATIONS = 40
COARSE_TAU_S = 3 * 3600.0
"""Spacing of the coarse grid of candidate start times [s]; refined to COARSE/18 around the best."""

Progress = Callable[[str], None]


@dataclass
class Finding:
    """One accepted effect with its fitted parameters and the evidence for it."""

    effect: Effect
    tau: int
    start: str | None  # ISO UTC, None = before the data
    amplitude: float
    summary: str
    evidence: str
    mae_before: float
    mae_after: float
    delta_bic: float
    trace: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """The fitted effect over the record: flux [W m-2 of floor] or sensor offset [K]."""
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


def compose(base: Model, effects: list[Effect], gh: Greenhouse, n: int, dt: float) -> Model:
    """Base model plus effect terms: flux effects, then capacity (wrapping all fluxes), then
    sensor terms."""
    model = base
    for e in effects:
        if e.kind == "flux":
            model = model.with_terms(e.build(base, gh, n, dt))
    for e in effects:
        if e.kind == "capacity":
            model = model.with_terms(e.build(model, gh, n, dt))
    for e in effects:
        if e.kind == "sensor":
            model = model.with_sensors(e.build(base, gh, n, dt))
    return model


def carry(theta: np.ndarray, old: Model, new: Model) -> np.ndarray:
    """Parameter vector for ``new``: values of ``old`` by name, the rest at their defaults."""
    out = new.defaults()
    for j, name in enumerate(new.names):
        if name in old.names:
            out[j] = theta[old.index(name)]
    return out


def heldout_blocks(split: int, n: int, dt: float) -> list[tuple[int, int]]:
    """The held-out part cut into blocks of one day, or a quarter of it when shorter."""
    length = n - split
    day = int(round(86400.0 / dt))
    block = day if length >= 4 * day else max(length // 4, 2)
    edges = list(range(split, n, block))
    blocks = [(a, min(a + block, n)) for a in edges]
    if len(blocks) > 1 and blocks[-1][1] - blocks[-1][0] < block // 2:
        a, _ = blocks.pop()
        blocks[-1] = (blocks[-1][0], n)
    return blocks


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
    import time as _time

    t_start = _time.perf_counter()
    say = progress or (lambda msg: None)
    if not 0.1 <= split <= 0.9:
        raise ValueError(f"split must be within [0.1, 0.9], got {split}")
    x = drivers(series, gh)
    n, dt = len(series), series.step
    s = int(round(split * n))
    horizon = max(int(round(HORIZON_S / dt)), 2)
    if s < 2 * horizon or n - s < 2 * horizon:
        raise ValueError(
            f"{series.source}: {n} samples of {dt:g} s are too few to diagnose: both the "
            f"calibration and the held-out part need at least {2 * HORIZON_S / 3600:g} h"
        )
    blocks = heldout_blocks(s, n, dt)
    folds = [[b for i, b in enumerate(blocks) if i % 2 == k] for k in (0, 1)]
    fit_sets = [[(0, s)] + folds[1 - k] for k in (0, 1)]  # fold k is judged on folds[k]

    # 1. base calibration on C
    say("calibrating the base model on the calibration part")
    theta = radiation_fit(base, x, base.defaults(gh), (0, s))
    lo, hi = base.bounds(gh)
    rad = base.radiation.parameter.name if base.radiation is not None else None
    free = [j for j, nm in enumerate(base.names) if nm != rad]
    shoot_c = Shooting(base, x, gh, dt, window_starts([(0, s)], horizon), horizon)
    theta = fit_swarm(shoot_c, theta, free, lo, hi, BASE_ITERATIONS, seed)
    base_theta = theta.copy()

    model = base
    thetas = [theta.copy(), theta.copy()]  # per fold
    theta_all = theta.copy()
    before_pred = _heldout(model, thetas, x, gh, dt, folds, s, n)
    findings: list[Finding] = []
    rejected: list[dict] = []
    effects: list[Effect] = []
    current_pred = before_pred
    all_set = [(0, n)]

    for _round in range(MAX_EFFECTS):
        candidates = [e for e in library if e not in effects]
        if not candidates:
            break
        say(f"round {_round + 1}: ranking {len(candidates)} candidate effects")
        ranked = _rank(base, model, theta_all, effects, candidates, x, gh, dt, n, horizon, all_set)
        accepted = False
        for scan_all, dbic_all in ranked[:TRIES_PER_ROUND]:
            if dbic_all >= 0:
                break
            e = scan_all.effect
            say(f"round {_round + 1}: trying {e.name}")
            new_model = compose(base, effects + [e], gh, n, dt)
            new_thetas, dbics = [], []
            for k in (0, 1):
                th, dbic = _fit_effect(new_model, model, thetas[k], e, x, gh, dt, n, horizon,
                                       fit_sets[k], seed + 17 * k)
                new_thetas.append(th)
                dbics.append(dbic)
            pred = _heldout(new_model, new_thetas, x, gh, dt, folds, s, n)
            verdict = _judge(current_pred, pred, x["t_in"], blocks, s)
            verdict["delta_bic"] = [float(v) for v in dbics]
            if max(dbics) < 0 and verdict["ok"]:
                th_all, dbic_full = _fit_effect(new_model, model, theta_all, e, x, gh, dt, n,
                                                horizon, all_set, seed + 101)
                findings.append(_finding(e, new_model, th_all, series, current_pred, pred,
                                         verdict, dbic_full, x, blocks, s))
                effects.append(e)
                model, thetas, theta_all, current_pred = new_model, new_thetas, th_all, pred
                accepted = True
                say(f"kept {e.name}: {findings[-1].summary}")
                break
            rejected.append({"effect": e.name, "reason": verdict["why"], "delta_bic": dbics})
        if not accepted:
            break

    meas = x["t_in"]
    _traces(findings, model, theta_all, x, gh)
    before = _metrics(meas, before_pred, s)
    after = _metrics(meas, current_pred, s)
    pers = _metrics(meas, _persistence(meas, blocks, s, n), s)
    an_before = res.analyse(series.time[s:], meas[s:] - before_pred["free_run"], x, s, dt)
    an_after = res.analyse(series.time[s:], meas[s:] - current_pred["free_run"], x, s, dt)
    calib_r = _calibration_free_run(model, theta_all, x, gh, dt, s)
    unexplained, signature = res.unexplained(an_after, calib_r, series.time, s)
    return Diagnosis(
        model=model, theta=theta_all, base_model=base, base_theta=base_theta, findings=findings,
        rejected=rejected, before=before, after=after, persistence=pers, unexplained=unexplained,
        signature=signature, split_index=s, blocks=blocks, time=series.time, measured=meas,
        pred_before=before_pred, pred_after=current_pred, analysis_before=an_before,
        analysis_after=an_after, seconds=_time.perf_counter() - t_start,
    )


def _traces(findings: list[Finding], model: Model, theta: np.ndarray, x, gh: Greenhouse) -> None:
    """Each finding's flux (physical W m-2) or sensor offset (K) along the measured state."""
    from gateway.diagnose.effects import physical_capacity

    unit = model.capacity(gh) / physical_capacity(gh)
    fluxes = model.fluxes(theta, x, x["t_in"])
    p = {k: v[:, 0] for k, v in model.columns(theta[None, :]).items()}
    for f in findings:
        if f.effect.kind == "sensor":
            term = next(t for t in model.sensors if t.name == "e_" + f.effect.name)
            f.trace = np.broadcast_to(term.offset(p, x, slice(0, len(x["t_in"]))), x["t_in"].shape)
            f.trace_unit = "K"
        else:
            f.trace = fluxes["q_" + f.effect.name] / unit
            f.trace_unit = "W m-2"


# -- steps -------------------------------------------------------------------------------------
def _tau_grid(n: int, dt: float, segments: list[tuple[int, int]]) -> np.ndarray:
    step = max(int(round(COARSE_TAU_S / dt)), 1)
    grid = np.arange(0, n, step)
    return grid.astype(float)


def _scan(shoot: Shooting, theta: np.ndarray, e: Effect, n: int, dt: float,
          segments: list[tuple[int, int]]) -> Scan:
    """Coarse τ grid, then a fine grid around the best coarse τ."""
    sse0, _ = shoot.sse(theta[None, :])
    coarse = scan_tau(shoot, theta, e, _tau_grid(n, dt, segments), float(sse0[0]))
    step = max(int(round(COARSE_TAU_S / dt)), 1)
    t_best = coarse.taus[coarse.best]
    fine_taus = np.unique(np.clip(t_best + np.linspace(-step, step, 37).round(), 0, n - 1))
    fine = scan_tau(shoot, theta, e, fine_taus, float(sse0[0]))
    return fine if fine.sse[fine.best] < coarse.sse[coarse.best] else coarse


def _bic_delta(sse_new: float, sse_old: float, n_pairs: int, horizon: int, k_new: int) -> float:
    """ΔBIC = n_e ln(SSE_new/SSE_old) + k ln(n_e) with n_e = pairs / horizon effective samples
    (residuals of one shooting window are strongly autocorrelated)."""
    n_e = max(n_pairs / horizon, 2.0)
    return float(n_e * np.log(max(sse_new, 1e-300) / max(sse_old, 1e-300)) + k_new * np.log(n_e))


def _rank(base, model, theta, effects, candidates, x, gh, dt, n, horizon, segments):
    """Each candidate's τ scan (other parameters held) on ``segments``, sorted by ΔBIC."""
    out = []
    starts = window_starts(segments, horizon)
    for e in candidates:
        new = compose(base, effects + [e], gh, n, dt)
        th = carry(theta, model, new)
        shoot = Shooting(new, x, gh, dt, starts, horizon)
        sse0, npair = shoot.sse(th[None, :])
        sc = _scan(shoot, th, e, n, dt, segments)
        out.append((sc, _bic_delta(sc.sse[sc.best], float(sse0[0]), npair, horizon, 2)))
    out.sort(key=lambda item: item[1])
    return out


def _fit_effect(new_model, old_model, theta_old, e, x, gh, dt, n, horizon, segments, seed):
    """τ scan then a joint refit (base parameters + amplitude, τ held) on ``segments``."""
    th = carry(theta_old, old_model, new_model)
    starts = window_starts(segments, horizon)
    shoot = Shooting(new_model, x, gh, dt, starts, horizon)
    sse_old, npair = shoot.sse(th[None, :])
    sc = _scan(shoot, th, e, n, dt, segments)
    th[new_model.index(e.tau_name)] = sc.taus[sc.best]
    th[new_model.index(e.amp_name)] = sc.amps[sc.best]
    lo, hi = new_model.bounds(gh)
    rad = new_model.radiation.parameter.name if new_model.radiation is not None else None
    free = [j for j, nm in enumerate(new_model.names) if nm != rad and not nm.startswith("tau_")]
    # a box around the current values: a refit, not a new search
    width = 0.3 * (hi - lo)
    lo2, hi2 = np.maximum(lo, th - width), np.minimum(hi, th + width)
    th = fit_swarm(shoot, th, free, lo2, hi2, REFIT_ITERATIONS, seed)
    sse_new, _ = shoot.sse(th[None, :])
    return th, _bic_delta(float(sse_new[0]), float(sse_old[0]), npair, horizon, 2)


def _heldout(model, thetas, x, gh, dt, folds, s, n) -> dict[str, np.ndarray]:
    """Cross-fitted held-out predictions: free runs restarted at each block start, one-step."""
    free = np.full(n - s, np.nan)
    one = np.full(n - s, np.nan)
    for k in (0, 1):
        th = thetas[k][None, :]
        if not folds[k]:
            continue
        o = model.one_step(th, x, gh, dt)[0]
        for a, b in folds[k]:
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


def _judge(before, after, meas, blocks, s) -> dict:
    """Is the held-out free-run error significantly lower after?"""
    eb = (before["free_run"] - meas[s:]) ** 2
    ea = (after["free_run"] - meas[s:]) ** 2
    ok = np.isfinite(eb) & np.isfinite(ea)
    d = []
    for a, b in blocks:
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
           f"block-paired t = {t:.2f} over {len(d)} blocks")
    return {"ok": bool(good), "why": why, "gain": gain, "t": t, "mae_before": mae_b, "mae_after": mae_a}


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


def _finding(e, model, theta, series, pred_before, pred_after, verdict, dbic, x, blocks, s):
    tau = int(round(theta[model.index(e.tau_name)]))
    amp = float(theta[model.index(e.amp_name)])
    start = None if tau <= 0 else str(series.time[tau]) + "Z"
    when = f"from {str(series.time[tau])[:16].replace('T', ' ')} UTC" if start else "throughout the data"
    summary = f"{e.describe(amp)} {when}"
    r = x["t_in"][s:] - pred_before["free_run"]
    sig = res.short_signature(series.time[s:], r, x, s, series.step)
    evidence = (f"{verdict['why']}; ΔBIC {dbic:.0f} on all data; residual before it: {sig}; "
                f"expected signature: {e.signature}")
    return Finding(e, tau, start, amp, summary, evidence, verdict["mae_before"], verdict["mae_after"], dbic)


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
        "rejected": d.rejected,
        "heldout": {"start": str(d.time[d.split_index]) + "Z", "end": str(d.time[-1]) + "Z",
                    "blocks": len(d.blocks)},
        "seconds": d.seconds,
    }

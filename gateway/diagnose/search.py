"""The add-best-effect loop (issue 4, issue 10): calibrate, rank effects, refit, judge on held-out
data (docs/effects.md, "How the diagnosis decides").

1. Fits run on a grid of at least ``FIT_STEP_S`` (T_in readings, block-mean inputs); the
   reported metrics are on the data's own grid.
2. Structural calibration of the base on the first ``split`` of the data (C) only (base.py).
3. The rest (H) is cut into blocks dealt into two folds; each fold is judged by a model fitted
   on C plus the other fold only (judge.py).
4. Candidates are ranked on all data by ΔBIC of their τ scan; the best ones are tried in turn:
   τ re-scanned and the base refitted jointly per fold, judged against the model so far refitted
   the same way without it (judge.py). The judge keeps one or none; repeat.
5. Held-out error before and after, beside persistence; the residual's signature.

Each effect carries its own part of the model and its second-output evidence (effects.py);
this loop never asks an effect's name.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, replace

import numpy as np

from gateway.diagnose import judge as jd
from gateway.diagnose import residuals as res
from gateway.diagnose.base import Progress, calibrate_base, carry, free_parameters
from gateway.diagnose.bic import EFFECTIVE_S, delta_bic, effective_samples
from gateway.diagnose.effects import LIBRARY, Effect, compose
from gateway.diagnose.fit import HORIZON_S, Scan, Shooting, coarsen, drivers, fit_lm, scan_tau, window_starts
from gateway.diagnose.result import Diagnosis, Finding, make_finding, to_json, traces
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model
from gateway.series import Series

__all__ = ["Diagnosis", "Finding", "diagnose", "to_json"]

FIT_STEP_S = 300.0
"""Coarsest grid the fits run on [s] (finer data is coarsened, see fit.coarsen)."""
MAX_EFFECTS = 3
TRIES_PER_ROUND = 3
REFIT_LM_ITERATIONS = 12
TAU_ROUNDS = 2
"""Alternations of τ scan and joint refit in ``_fit_effect``."""
COARSE_TAU_S = 3 * 3600.0
"""Spacing of the coarse grid of candidate start times [s]; refined to COARSE/36 around the best."""


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
    _check_length(series, s, n, horizon)  # before drivers(): it needs a first row
    x = drivers(coarse, gh)
    duration = float(x["_index"][-1])
    held = _Heldout.of(s, n, dt)
    model0, theta, structure_log = calibrate_base(base, gh, x, dt, s, horizon, seed, say)
    ctx = _Context(x, gh, dt, duration, horizon, s)
    state = _Search(ctx, model0, theta, held)
    for rnd in range(1, MAX_EFFECTS + 1):
        if not _search_round(ctx, state, library, rnd, series, seed, say):
            break
    d = _report(series, ctx, k, _Fit(model0, [theta, theta], theta), state)
    d.structure = structure_log
    d.seconds = _time.perf_counter() - t_start
    return d


@dataclass(frozen=True)
class _Fit:
    """A model and its parameters per fold (for the cross-fitted held-out prediction: fitted
    on each fold's fit set; the base's are its calibration, the same for both) and on all
    data (the reported ones)."""

    model: Model
    thetas: list[np.ndarray]
    theta_all: np.ndarray


@dataclass(frozen=True)
class _Candidate:
    """A candidate effect the judge passed (``_try_candidate``): the model so far with the
    effect added, its parameters per fold, its cross-fitted held-out prediction and the
    judge's verdict (its ``delta_bic`` filled in per fold)."""

    effect: Effect
    model: Model
    thetas: list[np.ndarray]
    pred: dict
    verdict: jd.Verdict


@dataclass(frozen=True)
class _EffectFit:
    """A candidate effect fitted on some segments (``_fit_effect``): its parameters and the
    BIC change against the model without it (plus the second output's evidence)."""

    theta: np.ndarray
    delta_bic: float


@dataclass
class _Heldout:
    """The held-out part [s, n) cut into blocks dealt into two folds, and each fold's fit set:
    the calibration part plus the other fold (fold j is judged on ``folds[j]``)."""

    n: int
    blocks: list[tuple[int, int]]
    folds: list[list[tuple[int, int]]]
    fit_sets: list[list[tuple[int, int]]]

    @classmethod
    def of(cls, s: int, n: int, dt: float) -> _Heldout:
        blocks = jd.heldout_blocks(s, n, dt)
        folds = jd.folds_of(blocks)
        return cls(n, blocks, folds, [[(0, s)] + folds[1 - j] for j in (0, 1)])


class _Search:
    """The loop's state: the base, the model so far (the base + the effects kept), its
    parameters per fold and on all data, its held-out prediction, and what was tried."""

    def __init__(self, ctx: _Context, model0: Model, theta: np.ndarray, held: _Heldout) -> None:
        self.model0, self.model, self.held = model0, model0, held
        self.effects: list[Effect] = []
        self.thetas = [theta.copy(), theta.copy()]  # per fold
        self.theta_all = theta.copy()
        self.current_pred = self.heldout(ctx, model0, self.thetas)
        self.findings: list[Finding] = []
        self.rejected: list[dict] = []
        self.trials: list[dict] = []

    def final(self) -> _Fit:
        """The model so far with its parameters per fold and on all data."""
        return _Fit(self.model, self.thetas, self.theta_all)

    def heldout(self, ctx: _Context, model: Model, thetas: list[np.ndarray]) -> dict:
        """Cross-fitted held-out predictions of ``model`` (judge.heldout)."""
        return jd.heldout(model, thetas, ctx.x, ctx.gh, ctx.dt, self.held.folds, ctx.split,
                          self.held.n)


def _search_round(ctx: _Context, st: _Search, library: tuple[Effect, ...], rnd: int,
                  series: Series, seed: int, say: Progress) -> bool:
    """One round of the add-best-effect loop: rank the effects not yet kept, try the best ones
    against the model so far refitted the same way, keep the one with the most evidence of
    those the judge passes. False when no candidate is left or none passes."""
    candidates = [e for e in library if e not in st.effects]
    if not candidates:
        return False
    say(f"round {rnd}: ranking {len(candidates)} candidate effects")
    n = st.held.n
    ranked = _rank(ctx, st.model0, st.model, st.theta_all, st.effects, candidates, [(0, n)])
    # the reference: the model so far, refitted on each fold's fit set as a candidate is
    ref = [_refit(ctx, st.model, st.thetas[j], st.held.fit_sets[j]) for j in (0, 1)]
    ref_pred = st.heldout(ctx, st.model, ref)
    passed: list[_Candidate] = []
    for scan_all, dbic_all in ranked[:TRIES_PER_ROUND]:
        if dbic_all >= 0:
            break
        tried = _try_candidate(ctx, st, scan_all.effect, ref_pred, rnd, seed, say)
        if tried is not None:
            passed.append(tried)
    if not passed:
        return False
    best = _pick(passed, ctx.x["t_in"], ctx.split, ctx.dt, st.rejected)
    e = best.effect
    full = _fit_effect(ctx, best.model, st.model, st.theta_all, e, [(0, n)], seed + 101,
                       latest=False)
    st.findings.append(make_finding(e, best.model, full.theta, series, st.current_pred,
                                    best.verdict, full.delta_bic, ctx.x, ctx.split))
    st.effects.append(e)
    st.model, st.thetas, st.theta_all = best.model, best.thetas, full.theta
    st.current_pred = best.pred
    say(f"kept {e.name}: {st.findings[-1].summary}")
    return True


def _try_candidate(ctx: _Context, st: _Search, e: Effect, ref_pred: dict, rnd: int, seed: int,
                   say: Progress) -> _Candidate | None:
    """Candidate ``e`` added to the model so far, fitted per fold and judged on the held-out
    folds against ``ref_pred``: the candidate when it passes, else None (logged in
    ``st.rejected``); every trial is logged in ``st.trials``."""
    say(f"round {rnd}: trying {e.name}")
    new_model = compose(st.model0, st.effects + [e], ctx.gh, ctx.duration)
    fitted = [_fit_effect(ctx, new_model, st.model, st.thetas[j], e, st.held.fit_sets[j],
                          seed + 17 * j) for j in (0, 1)]
    new_thetas = [f.theta for f in fitted]
    pred = st.heldout(ctx, new_model, new_thetas)
    starts = [float(th[new_model.index(e.tau_name)]) for th in new_thetas]
    verdict = jd.judge(st.current_pred, ref_pred, pred, ctx.x["t_in"], st.held.blocks,
                       ctx.split, ctx.dt, starts, ctx.last)
    verdict.delta_bic = [float(f.delta_bic) for f in fitted]  # second output included
    st.trials.append({"round": rnd, "effect": e.name, "ok": verdict.ok,
                      "delta_bic": verdict.delta_bic, **verdict.stats})
    if max(verdict.delta_bic) < 0 and verdict.ok:
        return _Candidate(e, new_model, new_thetas, pred, verdict)
    st.rejected.append({"effect": e.name, "reason": verdict.why, "delta_bic": verdict.delta_bic})
    return None


def _check_length(series: Series, s: int, n: int, horizon: int) -> None:
    """A clear error for data too short to split into a calibration and a held-out part."""
    if s < 3 * horizon or n - s < 2 * horizon:
        raise ValueError(
            f"{series.source}: {len(series)} samples of {series.step:g} s are too few to "
            f"diagnose: the calibration part needs at least {3 * HORIZON_S / 3600:g} h and "
            f"the held-out part {2 * HORIZON_S / 3600:g} h"
        )


def _pick(passed: list[_Candidate], t_in: np.ndarray, s: int, dt: float, rejected: list[dict]
          ) -> _Candidate:
    """The passed candidate with the most evidence; the others go to ``rejected`` with why."""
    score = jd.scores([c.verdict for c in passed], t_in, s, dt)
    order = np.argsort(score)
    for i in order[1:]:
        other = passed[i]
        rejected.append({"effect": other.effect.name, "reason": "passed, but a rival has "
                         f"more evidence (score {score[i]:.0f} vs {score[order[0]]:.0f},"
                         " fit ΔBIC with second output + held-out): " + other.verdict.why,
                         "delta_bic": other.verdict.delta_bic})
    return passed[order[0]]


def _report(series: Series, ctx: _Context, k: int, base: _Fit, st: _Search) -> Diagnosis:
    """Figures on the data's own grid (``k`` data samples to one fit step): held-out error of
    ``base`` and of the search's final model beside persistence, residuals; what the search
    found, rejected and tried."""
    gh, final, held = ctx.gh, st.final(), st.held
    xf = drivers(series, gh)
    nf, dtf = len(series), series.step
    sf = ctx.split * k
    fblocks = [(a * k, b * k if b < held.n else nf) for a, b in held.blocks]
    ffolds = [[(a * k, b * k if b < held.n else nf) for a, b in f] for f in held.folds]
    before_f = jd.heldout(base.model, base.thetas, xf, gh, dtf, ffolds, sf, nf)
    after_f = jd.heldout(final.model, final.thetas, xf, gh, dtf, ffolds, sf, nf)
    meas = xf["t_in"]
    traces(st.findings, final.model, final.theta_all, xf, gh, ctx.duration)
    an_before = res.analyse(series.time[sf:], meas[sf:] - before_f["free_run"], xf, sf, dtf)
    an_after = res.analyse(series.time[sf:], meas[sf:] - after_f["free_run"], xf, sf, dtf)
    calib_r = jd.calibration_free_run(final.model, final.theta_all, xf, gh, dtf, sf)
    unexplained, signature = res.unexplained(an_after, calib_r, series.time, sf,
                                             meas[sf:] - after_f["free_run"], xf)
    return Diagnosis(
        model=final.model, theta=final.theta_all, base_model=base.model,
        base_theta=base.theta_all, findings=st.findings, rejected=st.rejected,
        before=jd.metrics_of(meas, before_f, sf),
        after=jd.metrics_of(meas, after_f, sf),
        persistence=jd.metrics_of(meas, jd.persistence(meas, fblocks, sf, nf), sf),
        unexplained=unexplained, signature=signature, split_index=sf, blocks=fblocks,
        time=series.time, measured=meas, pred_before=before_f, pred_after=after_f,
        analysis_before=an_before, analysis_after=an_after, trials=st.trials,
    )


class _Context:
    """What every step of one diagnosis shares: drivers, greenhouse, grid, split."""

    def __init__(self, x, gh, dt, duration, horizon, split) -> None:
        self.x, self.gh, self.dt, self.duration = x, gh, dt, duration
        self.horizon, self.split = horizon, split
        self.last = jd.last_start(duration, float(x["_index"][split]))
        """The latest start an effect may have (judge.last_start)."""

    def shooting(self, model: Model, segments: list[tuple[int, int]]) -> Shooting:
        starts = window_starts(segments, self.horizon, skip=self.horizon)
        return Shooting(model, self.x, self.gh, self.dt, starts, self.horizon)


def _tau_grid(effect: Effect, last: float) -> np.ndarray:
    first = 0.0 if effect.from_start else COARSE_TAU_S
    return np.arange(first, last + 1.0, COARSE_TAU_S)


def _scan(shoot: Shooting, theta: np.ndarray, e: Effect, last: float,
          segments: list[tuple[int, int]], latest: bool = True) -> Scan:
    """Coarse τ grid up to ``last`` (judge.last_start), then a fine grid around the best coarse
    τ. With ``latest``, of the start
    times that fit equally well (SSE within one effective sample's share: a likelihood ratio of
    e) the latest is taken: "no change until the data shows it", so a judged block between two
    pieces of fit data is never predicted with a guessed effect; else the best one (the reported
    start). Starts are compared on the temperature's SSE with the second output's ΔBIC at each
    start added (``Scan.score``): where the temperature leaves the start open, the output that
    shows the change places it. An effect whose second output fixes its start (a transmission
    change on the measured inside radiation) takes τ and amplitude from there."""
    m = shoot.model
    if e.evidence.fits_start(m, shoot.x):
        first = 0.0 if e.from_start else COARSE_TAU_S
        tau, amp = e.evidence.scan(m, shoot.x, theta, segments, first, last)
        th = theta.copy()
        th[m.index(e.tau_name)], th[m.index(e.amp_name)] = tau, np.clip(amp, e.lower, e.upper)
        sse, npair = shoot.sse(th[None, :])
        return Scan(e, np.array([tau]), np.array([th[m.index(e.amp_name)]]), sse, npair)
    sse0, npair = shoot.sse(theta[None, :])
    rel = 1.0 / max(npair * shoot.dt / EFFECTIVE_S, 1.0)
    n_e = effective_samples(npair, shoot.dt)

    def pick(sc: Scan) -> Scan:
        ev = e.evidence.profile(m, shoot.x, theta, segments, sc.taus, sc.amps)
        sc = replace(sc, score=sc.sse * np.exp(ev / n_e))  # second output's ΔBIC added (bic.py)
        return sc.latest_of_best(rel) if latest else sc

    grid = _tau_grid(e, last)
    if len(grid) == 0:  # no start time leaves enough data after it
        return Scan(e, np.array([last]), np.array([e.neutral]), sse0, npair)
    coarse = pick(scan_tau(shoot, theta, e, grid, float(sse0[0])))
    t_best = coarse.taus[coarse.best]
    lo = 0.0 if e.from_start else shoot.dt
    fine_taus = np.unique(np.clip(t_best + np.linspace(-1, 1, 37) * COARSE_TAU_S, lo,
                                  max(last, lo)))
    fine = pick(scan_tau(shoot, theta, e, fine_taus, float(sse0[0])))
    return fine if fine.scores[fine.best] <= coarse.scores[coarse.best] * (1.0 + rel) else coarse


def _evidence(e: Effect, model, x, theta, segments, sc: Scan) -> float:
    return e.evidence.delta_bic(model, x, theta, segments, float(sc.taus[sc.best]),
                                float(sc.amps[sc.best]))


def _rank(ctx: _Context, base, model, theta, effects, candidates, segments):
    """Each candidate's τ scan (other parameters held) on ``segments``, sorted by ΔBIC (its
    second output's included)."""
    out = []
    for e in candidates:
        new = compose(base, effects + [e], ctx.gh, ctx.duration)
        th = carry(theta, model, new, ctx.gh)
        shoot = ctx.shooting(new, segments)
        sse0, npair = shoot.sse(th[None, :])
        sc = _scan(shoot, th, e, ctx.last, segments)
        dbic = delta_bic(sc.sse[sc.best], float(sse0[0]), effective_samples(npair, ctx.dt), 2)
        out.append((sc, dbic + _evidence(e, new, ctx.x, th, segments, sc)))
    out.sort(key=lambda item: item[1])
    return out


def _refit(ctx: _Context, model: Model, theta: np.ndarray, segments) -> np.ndarray:
    """``model`` refitted on ``segments`` (base parameters and amplitudes, starts held), as
    :func:`_fit_effect` refits a candidate: the judge's reference."""
    lo, hi = model.bounds(ctx.gh)
    return fit_lm(ctx.shooting(model, segments), theta.copy(), free_parameters(model), lo, hi,
                  REFIT_LM_ITERATIONS)


def fit_effect_at(ctx: _Context, new_model, old_model, theta_old, e: Effect, segments,
                  tau: float) -> _EffectFit:
    """``e`` fitted on ``segments`` as the search fits it (``_fit_effect``: amplitude scan,
    joint refit of the base parameters and amplitude, ``TAU_ROUNDS`` alternations), but with
    its start held at ``tau`` [s since the first row] instead of scanned: the oracle of a known
    start (tests/generality/headroom.py). The amplitude is always fitted on the temperature."""
    return _fit_effect(ctx, new_model, old_model, theta_old, e, segments, 0, latest=False,
                       at=tau)


def _fit_effect(ctx: _Context, new_model, old_model, theta_old, e: Effect, segments, seed,
                latest: bool = True, at: float | None = None) -> _EffectFit:
    """τ scan (``_scan``) then a joint refit (base parameters + amplitude, τ held) on
    ``segments``, alternated ``TAU_ROUNDS`` times while the SSE falls; with ``at``, τ is held
    there (an amplitude scan at that one start, ``fit_effect_at``).

    The base was calibrated on data that may hold the start of the change (the calibration
    part ends after it): with those parameters held, the first scan sees the change's first
    hours already fitted by the base and puts τ late (at the next piece of data the base cannot
    carry, typically the next morning). Refitted with the effect from that τ, the base is freed
    of the change and a second scan finds where it really starts (coordinate descent on τ and
    the other parameters; kept only when it lowers the SSE)."""
    th = carry(theta_old, old_model, new_model, ctx.gh)
    shoot = ctx.shooting(new_model, segments)
    sse_old, npair = shoot.sse(th[None, :])
    lo, hi = new_model.bounds(ctx.gh)
    free = free_parameters(new_model)
    if at is None and e.evidence.fits_start(new_model, ctx.x):
        free = [j for j in free if new_model.names[j] != e.amp_name]  # fixed by the 2nd output
    ja, jt = new_model.index(e.amp_name), new_model.index(e.tau_name)
    best, best_sse, sc_best = None, np.inf, None
    for _ in range(TAU_ROUNDS):
        if at is None:
            sc = _scan(shoot, th, e, ctx.last, segments, latest)
        else:
            sc = scan_tau(shoot, th, e, np.array([float(at)]), float(shoot.sse(th[None, :])[0][0]))
        trial = th.copy()
        trial[jt], trial[ja] = sc.taus[sc.best], sc.amps[sc.best]
        trial = fit_lm(shoot, trial, free, lo, hi, REFIT_LM_ITERATIONS)
        sse = float(shoot.sse(trial[None, :])[0][0])
        if best is not None and not sse < best_sse:
            break
        best, best_sse, sc_best = trial, sse, sc
        th = trial.copy()
        th[ja] = e.neutral  # the next scan starts from the refitted base without the effect
    k = len(new_model.names) - len(old_model.names)  # amplitude, start (+ an added store's h)
    dbic = delta_bic(best_sse, float(sse_old[0]), effective_samples(npair, ctx.dt), k)
    return _EffectFit(best, dbic + _evidence(e, new_model, ctx.x, best, segments, sc_best))

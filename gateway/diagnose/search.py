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

Each effect carries its own part of the model and its second-output evidence (effects.py; its
fits: effect_fit.py); this loop never asks an effect's name.

Public steps, for studies that replay the search (tests/generality/headroom.py) with the very
code ``diagnose`` runs: ``prepare`` (steps 1–3: the search's state on the calibrated base),
``search_round`` (one round of step 4, every candidate tried returned with its fold fits,
held-out prediction and verdict), ``try_effect`` (one candidate, optionally at a given start),
``fit_all`` (a candidate's reported fit on all data) and ``keep``.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import numpy as np

from gateway.diagnose import judge as jd
from gateway.diagnose import residuals as res
from gateway.diagnose.base import Progress, calibrate_base
from gateway.diagnose.effect_fit import Context, EffectFit, fit_effect, rank, refit
from gateway.diagnose.effects import LIBRARY, Effect, compose
from gateway.diagnose.fit import HORIZON_S, Scan, coarsen, drivers
from gateway.diagnose.result import Diagnosis, Finding, make_finding, to_json, traces
from gateway.diagnose.structure import Structured
from gateway.greenhouse import Greenhouse
from gateway.model.drivers import clock_of
from gateway.model.model import Model
from gateway.series import Series

__all__ = ["Diagnosis", "Finding", "Heldout", "Round", "Start", "State", "Tried", "diagnose",
           "fit_all", "keep", "prepare", "reference", "search_round", "to_json", "try_effect"]

FIT_STEP_S = 300.0
"""Coarsest grid the fits run on [s] (finer data is coarsened, see fit.coarsen)."""
MAX_EFFECTS = 3
TRIES_PER_ROUND = 3


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
    start = prepare(series, gh, base, split, seed, say)
    st = start.state
    for rnd in range(1, MAX_EFFECTS + 1):
        r = search_round(st, library, rnd, say)
        _log(st, rnd, r)
        if r.best is None:
            break
        keep(st, r.best, series, say)
    d = _report(series, start.k, _Fit(st.model0, [start.theta, start.theta], start.theta), st)
    d.structure = start.structure
    d.seconds = _time.perf_counter() - t_start
    return d


@dataclass(frozen=True)
class _Fit:
    """A model and its parameters per fold (for the cross-fitted held-out prediction: fitted
    on each fold's fit set; the base's are its calibration, the same for both) and on all
    data (the reported ones)."""

    model: Structured
    thetas: list[np.ndarray]
    theta_all: np.ndarray


@dataclass
class Heldout:
    """The held-out part [s, n) cut into blocks dealt into two folds, and each fold's fit set:
    the calibration part plus the other fold (fold j is judged on ``folds[j]``)."""

    n: int
    blocks: list[tuple[int, int]]
    folds: list[list[tuple[int, int]]]
    fit_sets: list[list[tuple[int, int]]]

    @classmethod
    def of(cls, s: int, n: int, dt: float) -> Heldout:
        """The blocks and folds of rows [s, n) on a grid of ``dt`` [s] (judge.heldout_blocks)."""
        blocks = jd.heldout_blocks(s, n, dt)
        folds = jd.folds_of(blocks)
        return cls(n, blocks, folds, [[(0, s)] + folds[1 - j] for j in (0, 1)])


class State:
    """The loop's state: the shared context, the base, the model so far (the base + the effects
    kept), its parameters per fold and on all data, its held-out prediction, and what was
    tried (``trials``) and rejected (``rejected``, with why)."""

    def __init__(self, ctx: Context, model0: Structured, theta: np.ndarray, held: Heldout) -> None:
        self.ctx = ctx
        self.model0, self.model, self.held = model0, model0, held
        self.effects: list[Effect] = []
        self.thetas = [theta.copy(), theta.copy()]  # per fold
        self.theta_all = theta.copy()
        self.current_pred = self.heldout(model0, self.thetas)
        self.findings: list[Finding] = []
        self.rejected: list[dict] = []
        self.trials: list[dict] = []

    def final(self) -> _Fit:
        """The model so far with its parameters per fold and on all data."""
        return _Fit(self.model, self.thetas, self.theta_all)

    def heldout(self, model: Structured, thetas: list[np.ndarray]) -> dict:
        """Cross-fitted held-out predictions of ``model`` (judge.heldout)."""
        ctx = self.ctx
        return jd.heldout(model, thetas, ctx.x, ctx.gh, ctx.dt, self.held.folds, ctx.split,
                          self.held.n)


@dataclass(frozen=True)
class Start:
    """What ``prepare`` builds before the search: the data on the fit grid (``coarse``, ``k``
    data rows to one fit row), the calibrated base's parameters and structure log, and the
    search's state on that base."""

    coarse: Series
    k: int
    theta: np.ndarray
    structure: list[dict]
    state: State


def fit_factor(series: Series) -> int:
    """Rows of ``series`` per step of the fit grid (``FIT_STEP_S``; 1 for coarser rows)."""
    return max(int(FIT_STEP_S // series.step), 1)


def split_index(series: Series, split: float) -> int:
    """Row of ``series`` where the held-out part starts (``Diagnosis.split_index``), known
    before the diagnosis runs: the first ``split`` of the fit grid's rows calibrate. A clear
    ValueError when the data is too short to split into the two parts."""
    k = fit_factor(series)
    n = len(series) // k  # the fit grid's rows (``coarsen``)
    s = int(round(split * n))
    _check_length(series, s, n, max(int(round(HORIZON_S / (series.step * k))), 2))
    return s * k


def prepare(series: Series, gh: Greenhouse, base: Model, split: float = 0.5, seed: int = 0,
            progress: Progress | None = None) -> Start:
    """Steps 1–3 of the module docstring, as ``diagnose`` runs them: ``series`` on the fit
    grid, the base calibrated on its first ``split`` (base.calibrate_base), the held-out
    folds, and the search's state with the base's cross-fitted held-out prediction."""
    say = progress or (lambda msg: None)
    if not 0.1 <= split <= 0.9:
        raise ValueError(f"split must be within [0.1, 0.9], got {split}")
    k = fit_factor(series)
    s = split_index(series, split) // k  # checks the length before drivers() needs a first row
    coarse = coarsen(series, k)
    n, dt = len(coarse), coarse.step
    horizon = max(int(round(HORIZON_S / dt)), 2)
    # the base's driver-only columns (``Model.prepare``: FluxTerm.derive) once, not at every
    # step of every run: elementwise, so the same numbers as computed at each step
    x = dict(base.prepare(drivers(coarse, gh)))
    held = Heldout.of(s, n, dt)
    model0, theta, structure_log = calibrate_base(base, gh, x, dt, s, horizon, seed, say)
    ctx = Context(x, gh, dt, float(x["_index"][-1]), horizon, s)
    return Start(coarse, k, theta, structure_log, State(ctx, model0, theta, held))


@dataclass(frozen=True)
class Tried:
    """A candidate effect tried against the model so far (``try_effect``): the model with it
    added, its fit on each fold's fit set (parameters, ΔBIC with the second output), its
    cross-fitted held-out prediction, the judge's verdict (``delta_bic`` filled in per fold)
    and the ΔBIC of its τ scan on all data that ranked it (None when not ranked)."""

    effect: Effect
    model: Structured
    fits: list[EffectFit]
    pred: dict
    verdict: jd.Verdict
    rank_dbic: float | None = None

    @property
    def thetas(self) -> list[np.ndarray]:
        """Its parameters per fold."""
        return [f.theta for f in self.fits]

    @property
    def starts(self) -> list[float]:
        """Its start per fold [s since the first row]."""
        return [float(th[self.model.index(self.effect.tau_name)]) for th in self.thetas]

    @property
    def passed(self) -> bool:
        """The judge keeps it, its fits lower the BIC on both folds' fit sets and (when ranked)
        its ranking scan did on all data: a candidate the round may pick."""
        ranked = self.rank_dbic is None or self.rank_dbic < 0
        return bool(self.verdict.ok and max(self.verdict.delta_bic) < 0 and ranked)


@dataclass(frozen=True)
class Round:
    """One round (``search_round``): the candidates ranked on all data (τ scan, ΔBIC), the
    judge's reference prediction (the model so far refitted per fold without an effect), every
    candidate tried in ranked order, passed or not, the one picked (None when none passed) and
    the passed ones it beat (``rejected`` entries)."""

    ranked: list[tuple[Scan, float]]
    reference: dict | None
    tried: list[Tried] = field(default_factory=list)
    best: Tried | None = None
    rivals: list[dict] = field(default_factory=list)


def reference(st: State) -> dict:
    """The judge's reference: the model so far refitted on each fold's fit set as a candidate
    is (effect_fit.refit), its cross-fitted held-out prediction."""
    ref = [refit(st.ctx, st.model, st.thetas[j], st.held.fit_sets[j]) for j in (0, 1)]
    return st.heldout(st.model, ref)


def search_round(st: State, library: tuple[Effect, ...] | list[Effect], rnd: int = 1,
                 say: Progress | None = None, tries: int | None = TRIES_PER_ROUND,
                 every: bool = False) -> Round:
    """One round of the add-best-effect loop on ``st`` (which it leaves as it is): rank the
    effects of ``library`` not yet kept, try the ``tries`` best (None: all) of those whose
    ranking lowers the BIC (``every``: also the others, which never pass: a study's view of
    what the search does not try) against the model so far refitted the same way, pick the
    one with the most evidence of those that pass. ``diagnose`` logs it (``_log``) and
    ``keep``s the pick."""
    say = say or (lambda msg: None)
    candidates = [e for e in library if e not in st.effects]
    if not candidates:
        return Round([], None)
    say(f"round {rnd}: ranking {len(candidates)} candidate effects")
    ranked = rank(st.ctx, st.model0, st.model, st.theta_all, st.effects, candidates,
                  [(0, st.held.n)])
    ref_pred = reference(st)
    tried: list[Tried] = []
    for scan_all, dbic_all in ranked[:tries]:
        if dbic_all >= 0 and not every:
            break
        say(f"round {rnd}: trying {scan_all.effect.name}")
        tried.append(try_effect(st, scan_all.effect, ref_pred, rank_dbic=float(dbic_all)))
    passed = [t for t in tried if t.passed]
    if not passed:
        return Round(ranked, ref_pred, tried)
    best, rivals = _pick(passed, st.ctx.x["t_in"], st.ctx.split, st.ctx.dt)
    return Round(ranked, ref_pred, tried, best, rivals)


def try_effect(st: State, e: Effect, ref_pred: dict, at: float | None = None,
               rank_dbic: float | None = None) -> Tried:
    """Candidate ``e`` added to the model so far, fitted on each fold's fit set
    (effect_fit.fit_effect; with ``at``, its start held there [s since the first row]: the
    oracle of a known start) and judged on the held-out folds against ``ref_pred``
    (``reference``)."""
    ctx = st.ctx
    new_model = compose(st.model0, st.effects + [e], ctx.gh, ctx.duration)
    fits = [fit_effect(ctx, new_model, st.model, st.thetas[j], e, st.held.fit_sets[j],
                       latest=at is None, at=at) for j in (0, 1)]
    pred = st.heldout(new_model, [f.theta for f in fits])
    starts = [float(f.theta[new_model.index(e.tau_name)]) for f in fits]
    verdict = jd.judge(st.current_pred, ref_pred, pred, ctx.x["t_in"], st.held.blocks,
                       ctx.split, ctx.dt, starts, ctx.last)
    verdict.delta_bic = [float(f.delta_bic) for f in fits]  # second output included
    return Tried(e, new_model, fits, pred, verdict, rank_dbic)


def fit_all(st: State, t: Tried) -> EffectFit:
    """``t``'s effect fitted on all data after the model so far (the best-fitting start, not
    the latest of the equally good): the finding's reported start and parameters."""
    return fit_effect(st.ctx, t.model, st.model, st.theta_all, t.effect, [(0, st.held.n)],
                      latest=False)


def keep(st: State, t: Tried, series: Series, say: Progress | None = None
         ) -> Finding:
    """Add ``t`` to the model so far: its finding (reported from ``fit_all``), its model, fold
    parameters and held-out prediction become the state's."""
    full = fit_all(st, t)
    ctx, e = st.ctx, t.effect
    st.findings.append(make_finding(e, t.model, full.theta, series, st.current_pred,
                                    t.verdict, full.delta_bic, ctx.x, ctx.split, ctx.gh))
    st.effects.append(e)
    st.model, st.thetas, st.theta_all = t.model, t.thetas, full.theta
    st.current_pred = t.pred
    if say is not None:
        say(f"kept {e.name}: {st.findings[-1].summary}")
    return st.findings[-1]


def _log(st: State, rnd: int, r: Round) -> None:
    """Every trial of round ``rnd`` into ``st.trials``; those that did not pass, then the passed
    ones the pick beat, into ``st.rejected`` with why."""
    for t in r.tried:
        v = t.verdict
        st.trials.append({"round": rnd, "effect": t.effect.name, "ok": v.ok,
                          "delta_bic": v.delta_bic, **v.stats})
        if not t.passed:
            st.rejected.append({"effect": t.effect.name, "reason": v.why,
                                "delta_bic": v.delta_bic})
    st.rejected.extend(r.rivals)


def _check_length(series: Series, s: int, n: int, horizon: int) -> None:
    """A clear error for data too short to split into a calibration and a held-out part."""
    if s < 3 * horizon or n - s < 2 * horizon:
        raise ValueError(
            f"{series.source}: {len(series)} samples of {series.step:g} s are too few to "
            f"diagnose: the calibration part needs at least {3 * HORIZON_S / 3600:g} h and "
            f"the held-out part {2 * HORIZON_S / 3600:g} h"
        )


def _pick(passed: list[Tried], t_in: np.ndarray, s: int, dt: float
          ) -> tuple[Tried, list[dict]]:
    """The passed candidate with the most evidence (judge.scores), and the others as
    ``rejected`` entries saying why."""
    score = jd.scores([c.verdict for c in passed], t_in, s, dt)
    order = np.argsort(score)
    rivals = []
    for i in order[1:]:
        other = passed[i]
        rivals.append({"effect": other.effect.name, "reason": "passed, but a rival has "
                       f"more evidence (score {score[i]:.0f} vs {score[order[0]]:.0f},"
                       " fit ΔBIC with second output + held-out): " + other.verdict.why,
                       "delta_bic": other.verdict.delta_bic})
    return passed[order[0]], rivals


def _report(series: Series, k: int, base: _Fit, st: State) -> Diagnosis:
    """Figures on the data's own grid (``k`` data samples to one fit step): held-out error of
    ``base`` and of the search's final model beside persistence, residuals; what the search
    found, rejected and tried."""
    ctx = st.ctx
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
    clock = clock_of(gh)  # time of day at the site (local solar time), not UTC's
    an_before = res.analyse(series.time[sf:], meas[sf:] - before_f["free_run"], xf, sf, dtf, clock)
    an_after = res.analyse(series.time[sf:], meas[sf:] - after_f["free_run"], xf, sf, dtf, clock)
    calib_r = jd.calibration_free_run(final.model, final.theta_all, xf, gh, dtf, sf)
    unexplained, signature = res.unexplained(an_after, calib_r, series.time, sf,
                                             meas[sf:] - after_f["free_run"], xf, clock)
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

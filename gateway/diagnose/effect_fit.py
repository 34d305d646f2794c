"""Fitting one candidate effect on some segments of the data: the τ scan, the joint refit of the
base parameters and the amplitude, and the ranking of candidates by ΔBIC (docs/effects.md,
"How the diagnosis decides", "Start times"). The search's round (search.py) calls these per
fold's fit set and on all data; the studies (tests/generality/tau_profile.py, effect_alone.py)
call them directly.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gateway.diagnose import judge as jd
from gateway.diagnose.base import carry, free_parameters
from gateway.diagnose.bic import EFFECTIVE_S, delta_bic, effective_samples
from gateway.diagnose.effects import Effect, compose
from gateway.diagnose.fit import Scan, Shooting, fit_lm, scan_tau, window_starts
from gateway.diagnose.structure import Structured
from gateway.greenhouse import Greenhouse

__all__ = ["COARSE_TAU_S", "REFIT_LM_ITERATIONS", "TAU_ROUNDS", "Context", "EffectFit",
           "fit_effect", "fit_effect_at", "rank", "refit", "scan"]

REFIT_LM_ITERATIONS = 12
TAU_ROUNDS = 2
"""Alternations of τ scan and joint refit in ``fit_effect``."""
COARSE_TAU_S = 3 * 3600.0
"""Spacing of the coarse grid of candidate start times [s]; refined to COARSE/36 around the best."""

Segments = list[tuple[int, int]]


class Context:
    """What every step of one diagnosis shares: drivers ``x`` on the fit grid of ``dt`` [s],
    greenhouse, the data's duration [s since the first row], the shooting horizon [rows] and
    the split index (the calibration part is rows [0, split))."""

    def __init__(self, x: dict, gh: Greenhouse, dt: float, duration: float, horizon: int,
                 split: int) -> None:
        self.x, self.gh, self.dt, self.duration = x, gh, dt, duration
        self.horizon, self.split = horizon, split
        self.last = jd.last_start(duration, float(x["_index"][split]))
        """The latest start an effect may have (judge.last_start)."""

    def shooting(self, model: Structured, segments: Segments) -> Shooting:
        """Multiple shooting of ``model`` over windows of the horizon inside ``segments``."""
        starts = window_starts(segments, self.horizon, skip=self.horizon)
        return Shooting(model, self.x, self.gh, self.dt, starts, self.horizon)


@dataclass(frozen=True)
class EffectFit:
    """A candidate effect fitted on some segments (``fit_effect``): its parameters and the
    BIC change against the model without it (plus the second output's evidence)."""

    theta: np.ndarray
    delta_bic: float


def _tau_grid(effect: Effect, last: float) -> np.ndarray:
    first = 0.0 if effect.from_start else COARSE_TAU_S
    return np.arange(first, last + 1.0, COARSE_TAU_S)


def scan(shoot: Shooting, theta: np.ndarray, e: Effect, last: float, segments: Segments,
         latest: bool = True) -> Scan:
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


def _evidence(e: Effect, model: Structured, x: dict, theta: np.ndarray, segments: Segments,
              sc: Scan) -> float:
    """The second output's ΔBIC for ``e`` at the scan's best start and amplitude."""
    return e.evidence.delta_bic(model, x, theta, segments, float(sc.taus[sc.best]),
                                float(sc.amps[sc.best]))


def rank(ctx: Context, base: Structured, model: Structured, theta: np.ndarray, effects: list[Effect],
         candidates: list[Effect], segments: Segments) -> list[tuple[Scan, float]]:
    """Each candidate's τ scan (other parameters held) on ``segments``, added to ``model`` (the
    ``base`` + ``effects``, parameters ``theta``), sorted by ΔBIC (its second output's
    included)."""
    out = []
    for e in candidates:
        new = compose(base, effects + [e], ctx.gh, ctx.duration)
        th = carry(theta, model, new, ctx.gh)
        shoot = ctx.shooting(new, segments)
        sse0, npair = shoot.sse(th[None, :])
        sc = scan(shoot, th, e, ctx.last, segments)
        dbic = delta_bic(sc.sse[sc.best], float(sse0[0]), effective_samples(npair, ctx.dt), 2)
        out.append((sc, dbic + _evidence(e, new, ctx.x, th, segments, sc)))
    out.sort(key=lambda item: item[1])
    return out


def refit(ctx: Context, model: Structured, theta: np.ndarray, segments: Segments) -> np.ndarray:
    """``model`` refitted on ``segments`` (base parameters and amplitudes, starts held), as
    :func:`fit_effect` refits a candidate: the judge's reference."""
    lo, hi = model.bounds(ctx.gh)
    return fit_lm(ctx.shooting(model, segments), theta.copy(), free_parameters(model), lo, hi,
                  REFIT_LM_ITERATIONS)


def fit_effect_at(ctx: Context, new_model: Structured, old_model: Structured, theta_old: np.ndarray,
                  e: Effect, segments: Segments, tau: float) -> EffectFit:
    """``e`` fitted on ``segments`` as the search fits it (``fit_effect``: amplitude scan,
    joint refit of the base parameters and amplitude, ``TAU_ROUNDS`` alternations), but with
    its start held at ``tau`` [s since the first row] instead of scanned: the oracle of a known
    start (as ``search.try_effect`` with ``at`` fits each fold: tests/generality/headroom.py).
    The amplitude is always fitted on the temperature."""
    return fit_effect(ctx, new_model, old_model, theta_old, e, segments, latest=False, at=tau)


def fit_effect(ctx: Context, new_model: Structured, old_model: Structured, theta_old: np.ndarray,
               e: Effect, segments: Segments, latest: bool = True,
               at: float | None = None) -> EffectFit:
    """τ scan (``scan``) then a joint refit (base parameters + amplitude, τ held) on
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
            sc = scan(shoot, th, e, ctx.last, segments, latest)
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
    if best is None or sc_best is None:  # the first round always sets them
        raise ValueError(f"fit_effect: no round ran (TAU_ROUNDS = {TAU_ROUNDS})")
    k = len(new_model.names) - len(old_model.names)  # amplitude, start (+ an added store's h)
    dbic = delta_bic(best_sse, float(sse_old[0]), effective_samples(npair, ctx.dt), k)
    return EffectFit(best, dbic + _evidence(e, new_model, ctx.x, best, segments, sc_best))

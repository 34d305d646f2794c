"""RIWPSO, BA and RSBA (thesis III.36–III.46, figure 9), vectorised over the population.

The population lives in box-normalised coordinates u in [0, 1]^k (x = lower + u (upper -
lower)), so one setting of the step scale sigma suits parameters of any magnitude: the thesis
works on raw values whose scales differ by decades, and its sigma "should be linked to the
scalings of the design variables" (Yang 2014). Every cost evaluation is one call with the whole
population, shape (P, k) → (P,). Coordinates leaving the box are redrawn uniformly inside it, as
the thesis does for both algorithms.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gateway.model.terms import const

CostFn = Callable[[np.ndarray], np.ndarray]
Progress = Callable[[int, float], None]


@dataclass
class SearchResult:
    """Best parameters found, their cost and the best cost after each iteration."""

    best: np.ndarray
    cost: float
    history: np.ndarray
    evaluations: int
    iterations: int


@dataclass(frozen=True)
class PSOSettings:
    """RIWPSO control parameters (§III.4.2.1.2.A)."""

    particles: int = 100
    iterations: int = 220
    w_min: float = 0.0
    w_max: float = 1.0
    c1: float = 2.0
    c2: float = 1.5
    tol: float = 1e-10  # stop once the best cost is below this


@dataclass(frozen=True)
class BatSettings:
    """BA / RSBA control parameters.

    Defaults are the offline settings of §III.4.2.1.2.A (100 bats, f in [0, 1.5], A0 = 1,
    r_i random with r0 = 0.1, alpha = gamma = 0.9, RSBA sigma in [1e-7, 1e-2], BA sigma 1e-2).
    """

    bats: int = 100
    iterations: int = 500
    f_min: float = 0.0
    f_max: float = 1.5
    loudness: float = 1.0
    r0: float = 0.1
    random_initial_rate: bool = True  # r_i drawn in [0, 1]; False: r_i = 0
    alpha: float = 0.9
    gamma: float = 0.9
    sigma_min: float = 1e-7
    sigma_max: float = 1e-2
    sigma: float = 1e-2  # standard BA's constant scale (III.43)
    tol: float = 0.0


ALMERIA_OFFLINE = BatSettings(
    bats=20, iterations=500, f_max=2.0, r0=0.2, random_initial_rate=False,
    alpha=0.8, gamma=0.8, sigma_min=1e-3, sigma_max=1.0,
)
"""RSBA settings of §IV.2.2.1.A (Almería offline calibration and online estimator)."""


def _to_raw(u: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            width: np.ndarray | None = None) -> np.ndarray:
    """x = lower + u (upper - lower); ``width`` = upper - lower when already known."""
    return lower + u * (upper - lower if width is None else width)


def _to_unit(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    width = np.where(upper > lower, upper - lower, 1.0)
    return np.clip((x - lower) / width, 0.0, 1.0)


_ZERO, _ONE = const(0.0), const(1.0)  # 0-d operands: numpy converts a Python float each call


def _redraw_outside(u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = (u < _ZERO) | (u > _ONE)
    if out.any():
        u = u.copy()
        u[out] = rng.random(int(out.sum()))
    return u


def _safe_cost(cost: CostFn, x: np.ndarray, fresh: bool = False) -> np.ndarray:
    """The costs of ``x`` with NaN and -inf as +inf. ``fresh``: the caller will not write into
    the result, so all-finite costs are returned as the cost function gave them (no copy)."""
    c = np.asarray(cost(x), dtype=float)
    if fresh and math.isfinite(np.add.reduce(c, axis=None)):  # one reduction: all finite
        return c
    return np.where(np.isfinite(c), c, np.inf)


def riwpso(
    cost: CostFn,
    lower: np.ndarray,
    upper: np.ndarray,
    settings: PSOSettings = PSOSettings(),
    rng: np.random.Generator | None = None,
    x0: np.ndarray | None = None,
    progress: Progress | None = None,
) -> SearchResult:
    """Random inertia weight PSO (III.36–III.38) minimising ``cost`` inside [lower, upper]."""
    rng = rng or np.random.default_rng()
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    n, k = settings.particles, len(lower)
    u = rng.random((n, k))
    if x0 is not None:
        u[0] = _to_unit(np.asarray(x0, float), lower, upper)
    v = np.zeros((n, k))
    fit = _safe_cost(cost, _to_raw(u, lower, upper))
    pbest, pcost = u.copy(), fit.copy()
    g = int(np.argmin(pcost))
    history = []
    evaluations = n
    it = 0
    for it in range(1, settings.iterations + 1):
        w = settings.w_min + (settings.w_max - settings.w_min) * rng.random()  # III.38
        r1, r2 = rng.random((n, k)), rng.random((n, k))
        v = w * v + settings.c1 * r1 * (pbest - u) + settings.c2 * r2 * (pbest[g] - u)  # III.37
        u = _redraw_outside(u + v, rng)  # III.36 and the out-of-range rule
        fit = _safe_cost(cost, _to_raw(u, lower, upper))
        evaluations += n
        better = fit < pcost
        pbest[better], pcost[better] = u[better], fit[better]
        g = int(np.argmin(pcost))
        history.append(pcost[g])
        if progress:
            progress(it, float(pcost[g]))
        if pcost[g] <= settings.tol:
            break
    return SearchResult(
        _to_raw(pbest[g], lower, upper), float(pcost[g]), np.array(history), evaluations, it
    )


def bat(
    cost: CostFn,
    lower: np.ndarray,
    upper: np.ndarray,
    settings: BatSettings = BatSettings(),
    variant: str = "rsba",
    rng: np.random.Generator | None = None,
    x0: np.ndarray | None = None,
    progress: Progress | None = None,
) -> SearchResult:
    """Bat algorithm: standard BA (III.40–III.43, III.46) or RSBA (III.44–III.45 replace the
    local walk: no loudness term, sigma redrawn in [sigma_min, sigma_max] every iteration).

    Acceptance follows Yang's BA: a bat moves to its new solution when it is no worse than its
    current one and ``rand < A_i`` (figure 9 prints ``f(x_i) < f(x_*)``, which would make a bat
    accept only solutions better than the global best and freeze the swarm). The global best is
    updated from every evaluated solution. ``x0`` seeds bat 0 (warm start of the online use).
    """
    if variant not in ("ba", "rsba"):
        raise ValueError(f"variant must be 'ba' or 'rsba', got {variant!r}")
    rng = rng or np.random.default_rng()
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    s = settings
    n, k = s.bats, len(lower)
    u = rng.random((n, k))
    if x0 is not None:
        u[0] = _to_unit(np.asarray(x0, float), lower, upper)
    v = np.zeros((n, k))
    width = upper - lower
    fit = _safe_cost(cost, _to_raw(u, lower, upper, width))
    loud = np.full(n, s.loudness)
    rate = rng.random(n) if s.random_initial_rate else np.zeros(n)
    g = int(np.argmin(fit))
    best_u, best_cost = u[g].copy(), float(fit[g])
    history = []
    evaluations = n
    sigma = s.sigma_max
    # the settings as 0-d operands (terms.const): the same float64 operations, cheaper per call
    f_min, f_span, alpha = const(s.f_min), const(s.f_max - s.f_min), const(s.alpha)
    it = 0
    for it in range(1, s.iterations + 1):
        freq = f_min + f_span * rng.random((n, 1))  # III.40
        v = v + (u - best_u) * freq  # III.41
        new = u + v  # III.42
        local = rng.random(n) > rate
        walkers = int(np.count_nonzero(local))
        if walkers:
            eps = rng.uniform(-1.0, 1.0, (walkers, k))
            if variant == "rsba":
                new[local] = best_u + const(sigma) * eps  # III.44
            else:
                new[local] = best_u + s.sigma * eps * loud.mean()  # III.43
        if variant == "rsba":
            sigma = s.sigma_min + (s.sigma_max - s.sigma_min) * rng.random()  # III.45
        new = _redraw_outside(new, rng)
        new_fit = _safe_cost(cost, _to_raw(new, lower, upper, width), fresh=True)
        evaluations += n
        accept = (new_fit <= fit) & (rng.random(n) < loud)
        if accept.any():  # late in a search most iterations move no bat
            u[accept], fit[accept] = new[accept], new_fit[accept]
            loud[accept] *= alpha  # III.46
            rate[accept] = s.r0 * (1.0 - np.exp(-s.gamma * it))
        j = int(new_fit.argmin())
        if new_fit[j] <= best_cost:
            best_u, best_cost = new[j].copy(), float(new_fit[j])
        history.append(best_cost)
        if progress:
            progress(it, best_cost)
        if best_cost <= s.tol:
            break
    return SearchResult(_to_raw(best_u, lower, upper), best_cost, np.array(history), evaluations, it)


@dataclass
class Algorithm:
    """A named search with its settings, callable as ``search(cost, lower, upper, rng, x0)``."""

    name: str
    settings: PSOSettings | BatSettings = field(default_factory=BatSettings)

    def __call__(self, cost, lower, upper, rng=None, x0=None, progress=None) -> SearchResult:
        if self.name == "riwpso":
            assert isinstance(self.settings, PSOSettings)
            return riwpso(cost, lower, upper, self.settings, rng, x0, progress)
        assert isinstance(self.settings, BatSettings)
        return bat(cost, lower, upper, self.settings, self.name, rng, x0, progress)

    @property
    def iterations(self) -> int:
        return self.settings.iterations


ALGORITHMS = ("riwpso", "ba", "rsba")


def make_algorithm(name: str, model_name: str = "prototype", iterations: int | None = None,
                   population: int | None = None) -> Algorithm:
    """The thesis settings for ``name`` on a model: §III.4.2.1.2.A for the prototype,
    §IV.2.2.1.A (20 bats, f in [0, 2], alpha = gamma = 0.8, sigma in [1e-3, 1]) otherwise."""
    if name not in ALGORITHMS:
        raise ValueError(f"unknown algorithm '{name}' (choose from {', '.join(ALGORITHMS)})")
    if name == "riwpso":
        st: PSOSettings | BatSettings = PSOSettings()
    elif model_name.startswith("prototype"):  # with or without the vent controller's term
        st = BatSettings()
    else:
        st = ALMERIA_OFFLINE
    from dataclasses import replace

    if iterations is not None:
        st = replace(st, iterations=iterations)
    if population is not None:
        if isinstance(st, PSOSettings):  # name == "riwpso"
            st = replace(st, particles=population)
        else:
            st = replace(st, bats=population)
    return Algorithm(name, st)

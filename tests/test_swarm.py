"""RIWPSO, BA and RSBA on known functions: vectorised calls, bounds kept, seeded."""

import numpy as np
import pytest

from gateway.estimate.swarm import BatSettings, PSOSettings, bat, make_algorithm, riwpso

LOWER = np.array([-5.0, 0.0, 1e-4])
UPPER = np.array([5.0, 10.0, 3e-4])
TARGET = np.array([1.3, 7.2, 2.2e-4])


class Sphere:
    """Scaled sphere with its minimum inside the box; records every call's population."""

    def __init__(self):
        self.calls = []

    def __call__(self, x):
        assert x.ndim == 2 and x.shape[1] == 3
        assert (x >= LOWER).all() and (x <= UPPER).all(), "a candidate left the box"
        self.calls.append(x.shape[0])
        return np.sum(((x - TARGET) / (UPPER - LOWER)) ** 2, axis=1)


@pytest.mark.parametrize("name", ["riwpso", "ba", "rsba"])
def test_each_algorithm_finds_the_minimum_with_whole_population_calls(name):
    cost = Sphere()
    algo = make_algorithm(name, iterations=300, population=40)
    res = algo(cost, LOWER, UPPER, rng=np.random.default_rng(3))
    assert set(cost.calls) == {40}  # one call per iteration with the whole population
    assert len(cost.calls) == res.iterations + 1
    assert res.evaluations == 40 * len(cost.calls)
    assert np.all(np.abs(res.best - TARGET) / (UPPER - LOWER) < 2e-2)
    assert np.all(np.diff(res.history) <= 0)  # best-so-far never gets worse


def test_same_seed_same_result_and_x0_is_used():
    a = bat(Sphere(), LOWER, UPPER, BatSettings(bats=20, iterations=50), "rsba", np.random.default_rng(9))
    b = bat(Sphere(), LOWER, UPPER, BatSettings(bats=20, iterations=50), "rsba", np.random.default_rng(9))
    assert np.array_equal(a.best, b.best)
    # A warm start at the optimum is never lost (the online estimator relies on it).
    c = riwpso(Sphere(), LOWER, UPPER, PSOSettings(particles=10, iterations=5), np.random.default_rng(0),
               x0=TARGET)
    assert c.cost == pytest.approx(0.0, abs=1e-20)


def test_rsba_beats_ba_on_a_narrow_valley():
    # The random scaling keeps refining where BA's loudness-scaled step stalls (III.43 vs III.44).
    def valley(x):
        u = (x - LOWER) / (UPPER - LOWER)
        return (u[:, 0] - 0.6) ** 2 + 100 * (u[:, 1] - u[:, 0] ** 2) ** 2 + (u[:, 2] - 0.3) ** 2

    settings = BatSettings(bats=30, iterations=400)
    ba = [bat(valley, LOWER, UPPER, settings, "ba", np.random.default_rng(s)).cost for s in range(5)]
    rsba = [bat(valley, LOWER, UPPER, settings, "rsba", np.random.default_rng(s)).cost for s in range(5)]
    assert np.median(rsba) < np.median(ba)


def test_non_finite_costs_are_treated_as_worst():
    def cost(x):
        c = np.sum((x - TARGET) ** 2, axis=1)
        c[::2] = np.nan
        return c

    res = riwpso(cost, LOWER, UPPER, PSOSettings(particles=10, iterations=20), np.random.default_rng(1))
    assert np.isfinite(res.cost)


def test_unknown_algorithm_is_a_clear_error():
    with pytest.raises(ValueError, match="choose from riwpso, ba, rsba"):
        make_algorithm("ga")


class FirstCallBest:
    """Cost 1 for the initial population and 2 for every later one, so the global best stays
    the seeded bat 0 and no bat ever moves; records every later population (raw units)."""

    def __init__(self) -> None:
        self.calls = 0
        self.populations: list[np.ndarray] = []

    def __call__(self, x: np.ndarray) -> np.ndarray:
        self.calls += 1
        if self.calls == 1:
            return np.ones(len(x))
        self.populations.append(x.copy())
        return np.full(len(x), 2.0)


def test_rsba_redraws_its_step_scale_uniformly_in_the_sigma_range_each_iteration():
    # III.44: every walker lands at best + sigma * eps, eps ~ U[-1, 1]^k (box-normalised);
    # III.45: sigma = sigma_min + (sigma_max - sigma_min) * rand, redrawn every iteration, the
    # first iteration using sigma_max. With the best pinned at the box centre, no acceptance
    # (r_i = 0 keeps every bat walking) and the range inside the box (no redraws), an
    # iteration's largest |u - 0.5| over 40 bats x 3 coordinates is its sigma to within ~3 %.
    lo, hi = 0.1, 0.4
    settings = BatSettings(bats=40, iterations=300, random_initial_rate=False,
                           sigma_min=lo, sigma_max=hi)
    cost = FirstCallBest()
    bat(cost, LOWER, UPPER, settings, "rsba", np.random.default_rng(5), x0=(LOWER + UPPER) / 2)
    spread = np.array([np.max(np.abs((x - LOWER) / (UPPER - LOWER) - 0.5))
                       for x in cost.populations])  # one per iteration, shape (300,)
    assert len(spread) == 300
    assert 0.95 * hi <= spread[0] <= hi  # the first step uses sigma_max
    later = spread[1:]
    assert later.max() <= hi and later.min() >= 0.95 * lo  # never outside [sigma_min, sigma_max]
    # Uniform over the range: each quarter holds about a quarter of the iterations (binomial
    # sd 0.025 for 299 draws; the 3 % shrink of the max only shifts edges slightly).
    edges = lo + (hi - lo) * np.array([0.25, 0.5, 0.75])
    quarters = np.diff(np.concatenate([[0], np.searchsorted(np.sort(later / 0.985), edges),
                                       [len(later)]])) / len(later)
    assert np.all(np.abs(quarters - 0.25) < 0.1), quarters
    assert np.mean(np.abs(np.diff(later)) > 0.01 * (hi - lo)) > 0.9  # redrawn every iteration

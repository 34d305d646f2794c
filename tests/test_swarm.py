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


def _walk_scales(iterations: int = 60) -> np.ndarray:
    """Every bat on the local walk around a best held at the centre (bat 0 starts there at
    cost 0, which nothing beats; r0 = 0 keeps every pulse rate at 0, no frequency term): each
    iteration's candidates are best + sigma ε with ε uniform in [-1, 1]^k, so their largest
    distance from the centre reads that iteration's step scale sigma (600 draws of ε: its largest
    |ε| is above 0.99 but for a chance of 0.25 %)."""
    seen: list[np.ndarray] = []

    def cost(x: np.ndarray) -> np.ndarray:
        seen.append(x.copy())
        return np.sum((x - 0.5) ** 2, axis=1)

    s = BatSettings(bats=200, iterations=iterations, f_min=0.0, f_max=0.0, r0=0.0,
                    random_initial_rate=False, sigma_min=0.01, sigma_max=0.4, tol=-1.0)
    bat(cost, np.zeros(3), np.ones(3), s, "rsba", np.random.default_rng(8), x0=np.full(3, 0.5))
    return np.array([np.abs(x - 0.5).max() for x in seen[1:]])  # seen[0]: the initial swarm


def test_rsba_redraws_its_step_scale_every_iteration():
    """RSBA's local walk (III.44) with sigma redrawn uniformly in [sigma_min, sigma_max] every
    iteration (III.45): the first iteration walks at sigma_max (the start value), the next ones
    at scales spread over the whole range."""
    scales = _walk_scales()
    assert scales[0] == pytest.approx(0.4, rel=0.02)
    later = scales[1:]
    assert np.all((later >= 0.01 * 0.98) & (later <= 0.4 * 1.0001)), later
    assert later.min() < 0.1 and later.max() > 0.33, (later.min(), later.max())
    assert np.std(later) > 0.06, np.std(later)  # uniform on [0.01, 0.4]: sd 0.113

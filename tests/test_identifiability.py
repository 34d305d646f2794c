"""Thesis §III.4.2.1.2 (table 4): recover assumed prototype parameters from simulated data.

The dataset (training/data/identifiability_prototype_2days.csv) is two days of real Bleiswijk
weather scaled towards a Biskra winter, driving the prototype model with the assumed values.
"""

from dataclasses import replace

import numpy as np
import pytest

from gateway.estimate.calibrate import calibrate
from gateway.estimate.swarm import make_algorithm
from gateway.model import build_model
from gateway.series import load_series
from training.identifiability import ASSUMED, DATASET, build


@pytest.fixture(scope="module")
def data(prototype_gh):
    return load_series(DATASET), build_model("prototype", prototype_gh)


def relative_errors(params):
    return {k: abs(params[k] - v) / v for k, v in ASSUMED.items()}


def test_shipped_dataset_is_the_documented_simulation(data):
    series, _ = data
    rebuilt = build()
    assert len(series) == 2880
    np.testing.assert_allclose(series["t_in"], rebuilt["t_in"], atol=1e-9)


def test_riwpso_recovers_every_parameter_within_half_a_percent(data, prototype_gh):
    series, model = data
    # Thesis settings (100 particles, c1 = 2, c2 = 1.5, w in [0, 1]); the thesis stops on a
    # tolerance: ours is 1e-13 °C² MSE, reached in 250–460 iterations over seeds 0–3.
    algo = make_algorithm("riwpso")
    algo.settings = replace(algo.settings, iterations=1000, tol=1e-13)
    result = calibrate(model, series, prototype_gh, algo, seed=0)
    errors = relative_errors(result.params)
    assert max(errors.values()) < 0.005, errors


def test_rsba_recovers_every_parameter_within_one_percent(data, prototype_gh):
    series, model = data
    # Thesis settings (100 bats, f in [0, 1.5], sigma in [1e-7, 1e-2] of the box). RSBA's
    # uniform sigma refines slowly: c_loss (the least sensitive parameter, as in table 4)
    # needs ~2000 iterations to fall under 1 % (tests/bench/calibration.py reports 10 seeds).
    result = calibrate(model, series, prototype_gh, make_algorithm("rsba", iterations=2500), seed=0)
    errors = relative_errors(result.params)
    assert max(errors.values()) < 0.01, errors

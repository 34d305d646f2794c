"""Thesis §III.4.2.1.2 (table 4): recover assumed prototype parameters from simulated data.

The dataset (training/data/identifiability_prototype_2days.csv) is two days of real Bleiswijk
weather scaled towards a Biskra winter, driving the prototype equations with the assumed values:
since issue 10 integrated by the independent fine RK4 reference (training/step_reference.py,
drivers moving within the minute) and stored as the kit's per-minute means, so the swarms must
find the parameters through the model's own integration, not the one that made the data.
"""

from dataclasses import replace

import numpy as np
import pytest

from gateway.estimate.calibrate import calibrate
from gateway.estimate.objective import Objective
from gateway.estimate.swarm import make_algorithm
from gateway.model import build_model
from gateway.model.drivers import prepare_drivers
from training.identifiability import ASSUMED, DATASET, build, load, main


@pytest.fixture(scope="module")
def data(prototype_gh):
    return load(), build_model("prototype", prototype_gh)


def relative_errors(params):
    return {k: abs(params[k] - v) / v for k, v in ASSUMED.items()}


def test_shipped_dataset_is_the_documented_simulation(data):
    series, _ = data
    rebuilt = build()
    assert len(series) == 2880 and series.sampling == "mean"
    for name in ("t_in", "t_out", "i_glob", "wind"):
        np.testing.assert_allclose(series[name], rebuilt[name], atol=1e-9)


def test_the_command_rebuilds_the_shipped_file_byte_for_byte(tmp_path, capsys):
    out = tmp_path / "rebuilt.csv"
    assert main(["--out", str(out)]) == 0
    assert out.read_bytes() == DATASET.read_bytes()
    with pytest.raises(SystemExit) as exit_:  # --help writes nothing, the shipped file least
        main(["--help"])
    assert exit_.value.code == 0 and "--out FILE.csv" in capsys.readouterr().out


def floor_cost(series, model, gh) -> float:
    """The one-step cost at the assumed values: the data are not the model's own, so the cost
    has a floor (~9.8e-8 °C², the step's own bias, docs/model.md)."""
    assumed = np.array([[ASSUMED[n] for n in model.names]])
    return float(Objective(model, prepare_drivers(series, gh), gh, 60.0, np.arange(4), assumed[0],
                           [(0, len(series))])(assumed)[0])


def test_riwpso_recovers_every_parameter_within_half_a_percent(data, prototype_gh):
    series, model = data
    # Thesis settings (100 particles, c1 = 2, c2 = 1.5, w in [0, 1]); the thesis stops on a
    # tolerance: ours is the cost at the assumed values, reached in < 300 iterations.
    algo = make_algorithm("riwpso")
    algo.settings = replace(algo.settings, iterations=1000, tol=floor_cost(series, model, prototype_gh))
    result = calibrate(model, series, prototype_gh, algo, seed=0)
    errors = relative_errors(result.params)
    assert max(errors.values()) < 0.005, errors


def test_rsba_recovers_every_parameter_within_one_percent(data, prototype_gh):
    series, model = data
    # Thesis settings (100 bats, f in [0, 1.5], sigma in [1e-7, 1e-2] of the box). RSBA's
    # uniform sigma refines slowly: c_loss (the least sensitive parameter, as in table 4) can
    # need ~2000 iterations to fall under 1 % (tests/bench/calibration.py: 10 seeds at 2500,
    # worst error median 0.47 %, max 0.78 %). Seed 0 is under 1 % from iteration ~385 on
    # (0.65 % at 500, 0.53 % at 750, 0.22 % at 2500): 700 iterations keep the claim at a
    # quarter of the time. A broken search (no local walk, III.44) stays above 1 % here.
    result = calibrate(model, series, prototype_gh, make_algorithm("rsba", iterations=700), seed=0)
    errors = relative_errors(result.params)
    assert max(errors.values()) < 0.01, errors

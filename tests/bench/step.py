"""What the issue-10 step costs: the default step against ``step.FROZEN`` (the step before it),
side by side in one run, on one core, as CPU-time ratios: each round times one then the other
right after, and the summary is the median of the rounds' ratios (the CPU time of an operation
also grows when the machine's other jobs share the core's caches, so only ratios taken close in
time are steady).

(a) the calibration cost of the thesis task (prototype, 2880 one-minute rows, a population of
    100, one-step-ahead: ``Objective``'s fast path), per population;
(b) a free run of 2880 steps for a population of 20 (prototype);
(c) the online estimator (almeria, thesis settings: 20 bats, 50 iterations, n = 3) on 120
    daytime minutes of the reference simulator, median per update.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import one_core, write_result  # noqa: E402

one_core()

import numpy as np  # noqa: E402

from gateway.estimate.objective import Objective  # noqa: E402
from gateway.estimate.online import OnlineEstimator, online_settings  # noqa: E402
from gateway.greenhouse import load_greenhouse  # noqa: E402
from gateway.model import build_model  # noqa: E402
from gateway.model.drivers import prepare_drivers  # noqa: E402
from gateway.model.step import FROZEN, Integration  # noqa: E402
from gateway.series import Series  # noqa: E402
from training.identifiability import load  # noqa: E402

ROUNDS = 5
SCHEMES = {"default": Integration(), "frozen": FROZEN}


def _cpu(fn, repeat: int = 1) -> float:
    c0 = time.process_time()
    for _ in range(repeat):
        fn()
    return (time.process_time() - c0) / repeat


def _objective_and_free_run():
    gh = load_greenhouse("biskra-prototype")
    series = load()
    x = prepare_drivers(series, gh)
    out = {}
    for label, scheme in SCHEMES.items():
        model = replace(build_model("prototype", gh), integration=scheme)
        obj = Objective(model, x, gh, 60.0, np.arange(4), model.defaults(gh), [(0, len(series))])
        lo, hi = model.bounds(gh)
        pop = lo + np.random.default_rng(0).random((100, 4)) * (hi - lo)
        few = pop[:20]
        out[label] = (lambda obj=obj, pop=pop: obj(pop),
                      lambda model=model, few=few: model.free_run(few, x, gh, 60.0))
    return out


def _online():
    from training.simulate import simulate

    r = simulate(plant="almeria", weather="almeria", start="2020-03-27", days=1, seed=1)
    series = Series(r.time, 60.0, {k: np.asarray(v, float) for k, v in r.columns.items()})
    rows = [{k: float(v[t]) for k, v in series.columns.items()} for t in range(len(series))]
    gh = load_greenhouse("almeria-palmerillas")
    out = {}
    for label, scheme in SCHEMES.items():
        model = replace(build_model("almeria", gh), integration=scheme)

        def run(model=model):
            est = OnlineEstimator(model, gh, model.defaults(gh), online_settings(model, gh))
            for row in rows[8 * 60 - 61 : 8 * 60]:
                est.update(row)
            times = []
            for row in rows[8 * 60 : 8 * 60 + 120]:
                c0 = time.process_time()
                est.update(row)
                times.append(time.process_time() - c0)
            return float(np.median(times))

        out[label] = run
    return out


def run() -> dict:
    calib = _objective_and_free_run()
    online = _online()
    rounds: list[dict[str, dict[str, float]]] = []
    for _ in range(ROUNDS):
        r: dict[str, dict[str, float]] = {k: {} for k in SCHEMES}
        for what in ("objective_ms", "free_run_ms", "online_update_ms"):
            for label in SCHEMES:
                cost, free = calib[label]
                if what == "objective_ms":
                    r[label][what] = 1e3 * _cpu(cost, 5)
                elif what == "free_run_ms":
                    r[label][what] = 1e3 * _cpu(free)
                else:
                    r[label][what] = 1e3 * online[label]()
        rounds.append(r)
    keys = list(rounds[0]["default"])
    ratios = {k: float(np.median([r["default"][k] / r["frozen"][k] for r in rounds])) for k in keys}
    best = {label: {k: min(r[label][k] for r in rounds) for k in keys} for label in SCHEMES}
    return {"cpu_ms_best_of_rounds": best, "rounds": rounds,
            "summary": {"default_over_frozen_median_of_rounds": ratios}}


if __name__ == "__main__":
    result = run()
    print(write_result("step", result))
    import json

    print(json.dumps(result, indent=2))

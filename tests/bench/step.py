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

``--against REF`` (a git commit or branch) also measures the code of REF, exported by
``git archive`` to a temporary folder: each round runs one process on REF's tree and one on this
tree, alternately, both with this bench's measurement (``--round``), and the summary adds the
median of the rounds' ratios this tree / REF. Run it under ``nice`` on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
# The tree under test first (this checkout, or the one --against exported): tests/bench/gateway.py
# must not shadow the gateway package.
sys.path.insert(0, os.environ.get("SERRA_TREE", str(HERE.parents[1])))
from _common import against as against_rounds  # noqa: E402
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


def _round(calib, online) -> dict[str, dict[str, float]]:
    """One round: each figure for the default step, then for FROZEN right after."""
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
    return r


def _median_ratio(rounds: list, num, den) -> dict[str, float]:
    keys = list(num(rounds[0]))
    return {k: float(np.median([num(r)[k] / den(r)[k] for r in rounds])) for k in keys}


def run(against: str | None = None) -> dict:
    if against is None:
        calib, online = _objective_and_free_run(), _online()
        rounds = [_round(calib, online) for _ in range(ROUNDS)]
        base = None
    else:
        base, rounds = against_rounds(__file__, against, ROUNDS)
    keys = list(rounds[0]["default"])
    best = {label: {k: min(r[label][k] for r in rounds) for k in keys} for label in SCHEMES}
    summary = {"default_over_frozen_median_of_rounds":
               _median_ratio(rounds, lambda r: r["default"], lambda r: r["frozen"]),
               "default_cpu_ms_median_of_rounds":
               {k: float(np.median([r["default"][k] for r in rounds])) for k in keys}}
    out = {"cpu_ms_best_of_rounds": best, "rounds": rounds, "summary": summary}
    if base is not None:
        i = list(range(len(rounds)))
        for label in SCHEMES:
            summary[f"{label}_this_over_{against}_median_of_rounds"] = _median_ratio(
                i, lambda j, lab=label: rounds[j][lab], lambda j, lab=label: base[j][lab])
        summary[f"default_cpu_ms_median_of_rounds_at_{against}"] = {
            k: float(np.median([r["default"][k] for r in base])) for k in keys}
        out[f"rounds_at_{against}"] = base
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--against", metavar="REF", help="also measure this git commit's code")
    parser.add_argument("--round", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.round:  # one round in this process, JSON on the last line (used by --against)
        print(json.dumps(_round(_objective_and_free_run(), _online())))
        raise SystemExit(0)
    result = run(args.against)
    print(write_result("step", result))
    print(json.dumps(result["summary"], indent=2))

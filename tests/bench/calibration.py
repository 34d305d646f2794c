"""Calibration bench (issue: thesis task timing and peers side by side in one run).

(a) The thesis identification task: 4 parameters, 2880 one-minute samples, 100 particles,
    220 iterations (RIWPSO), one-step-ahead cost, on one core. Goal ≤ 5 s.
(b) The same objective solved by mealpy's BA and PSO (per-solution objective calls) and by
    pyswarms' global-best PSO (whole-swarm calls) at an equal number of evaluations: time per
    evaluation and final cost, ours vs theirs. Goal: ≥ 10× faster per evaluation, cost ≤ theirs.
(c) BA vs RSBA over 10 seeds (thesis table 5): median final cost, and RSBA/RIWPSO parameter
    errors (table 4).

``--against REF`` (a git commit or branch) measures only (a) with RIWPSO, this tree against
REF's code exported by ``git archive``, in interleaved rounds (one process per tree per round,
each the best of 3 CPU times): the median of the rounds' ratios, steadier on a noisy machine
than either time (``bench/results/calibration_against.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The tree under test first (this checkout, or the one --against exported): tests/bench/gateway.py
# must not shadow the gateway package.
sys.path.insert(0, os.environ.get("SERRA_TREE", str(Path(__file__).resolve().parents[2])))
from _common import against, one_core, write_result  # noqa: E402

one_core()

import numpy as np  # noqa: E402

from gateway.estimate.calibrate import calibrate  # noqa: E402
from gateway.estimate.objective import Objective  # noqa: E402
from gateway.estimate.swarm import make_algorithm  # noqa: E402
from gateway.greenhouse import load_greenhouse  # noqa: E402
from gateway.model import build_model  # noqa: E402
from gateway.model.drivers import prepare_drivers  # noqa: E402
from training.identifiability import ASSUMED, load  # noqa: E402

PARTICLES, ITERATIONS = 100, 220
ROUNDS = 3
AGAINST_ROUNDS = 4


def _problem():
    gh = load_greenhouse("biskra-prototype")
    model = build_model("prototype", gh)
    series = load()  # per-minute means of the RK4 reference (docs/model.md)
    x = prepare_drivers(series, gh)
    idx = np.arange(len(model.names))
    obj = Objective(model, x, gh, 60.0, idx, model.defaults(gh), [(0, len(series))])
    lo, hi = model.bounds(gh)
    return gh, model, series, obj, lo, hi


class Counted:
    """Wraps a cost to count evaluated candidates."""

    def __init__(self, fn):
        self.fn, self.n = fn, 0

    def __call__(self, x):
        x = np.atleast_2d(x)
        self.n += x.shape[0]
        return self.fn(x)


def ours(obj, lo, hi, name, seed, iterations=ITERATIONS, population=PARTICLES):
    algo = make_algorithm(name, iterations=iterations, population=population)
    algo.settings = replace(algo.settings, tol=0.0)  # run every iteration: a fair timing
    cost = Counted(obj)
    t0 = time.perf_counter()
    res = algo(cost, lo, hi, rng=np.random.default_rng(seed))
    dt = time.perf_counter() - t0
    return {"seconds": dt, "evaluations": cost.n, "us_per_eval": dt / cost.n * 1e6, "cost": res.cost}


def mealpy_run(obj, lo, hi, kind, seed, evaluations):
    from mealpy import BA, PSO, FloatVar

    cost = Counted(obj)
    problem = {
        "obj_func": lambda sol: float(cost(np.asarray(sol)[None, :])[0]),
        "bounds": FloatVar(lb=lo.tolist(), ub=hi.tolist()),
        "minmax": "min",
        "log_to": None,
    }
    epochs = max(1, evaluations // PARTICLES - 1)
    opt = BA.OriginalBA(epoch=epochs, pop_size=PARTICLES) if kind == "ba" else PSO.OriginalPSO(
        epoch=epochs, pop_size=PARTICLES, c1=2.0, c2=1.5)
    t0 = time.perf_counter()
    best = opt.solve(problem, seed=seed)
    dt = time.perf_counter() - t0
    return {"seconds": dt, "evaluations": cost.n, "us_per_eval": dt / cost.n * 1e6,
            "cost": float(best.target.fitness)}


def pyswarms_run(obj, lo, hi, seed, evaluations):
    import logging

    import pyswarms as ps

    logging.getLogger("pyswarms").setLevel(logging.ERROR)
    np.random.seed(seed)  # noqa: NPY002 -- pyswarms draws from the legacy global generator
    cost = Counted(obj)
    opt = ps.single.GlobalBestPSO(
        n_particles=PARTICLES, dimensions=len(lo), options={"c1": 2.0, "c2": 1.5, "w": 0.5},
        bounds=(lo, hi),
    )
    t0 = time.perf_counter()
    best_cost, _ = opt.optimize(cost, iters=max(1, evaluations // PARTICLES - 1), verbose=False)
    dt = time.perf_counter() - t0
    return {"seconds": dt, "evaluations": cost.n, "us_per_eval": dt / cost.n * 1e6, "cost": float(best_cost)}


def run() -> dict:
    gh, model, series, obj, lo, hi = _problem()
    result: dict = {"task": {"parameters": 4, "samples": len(series), "particles": PARTICLES,
                             "iterations": ITERATIONS, "cost": "one-step-ahead MSE [°C²]"}}
    # Alternating rounds, best of 3 for each contender: the machine's load changes over a run,
    # so contenders are interleaved and each keeps its fastest round (same seed, same result).
    evaluations = PARTICLES * (ITERATIONS + 1)
    contenders = {
        "riwpso": lambda: ours(obj, lo, hi, "riwpso", seed=0),
        "rsba": lambda: ours(obj, lo, hi, "rsba", seed=0),
        "ba": lambda: ours(obj, lo, hi, "ba", seed=0),
        "mealpy_ba": lambda: mealpy_run(obj, lo, hi, "ba", 0, evaluations),
        "mealpy_pso": lambda: mealpy_run(obj, lo, hi, "pso", 0, evaluations),
        "pyswarms_gbest": lambda: pyswarms_run(obj, lo, hi, 0, evaluations),
    }
    best: dict[str, dict] = {}
    for _ in range(ROUNDS):
        for label, fn in contenders.items():
            try:
                r = fn()
            except Exception as exc:  # a peer that fails to import or run is reported, not fatal
                best[label] = {"error": f"{type(exc).__name__}: {exc}"}
                continue
            if label not in best or r["seconds"] < best[label].get("seconds", float("inf")):
                best[label] = r
    thesis = {k: best[k] for k in ("riwpso", "rsba", "ba")}
    result["thesis_task"] = thesis
    peers = {k: best[k] for k in ("mealpy_ba", "mealpy_pso", "pyswarms_gbest")}
    result["peers"] = peers
    ratios = {}
    for label, peer in peers.items():
        if "error" in peer:
            continue
        mine = thesis["rsba"] if label == "mealpy_ba" else thesis["riwpso"]
        ratios[label] = {
            "speedup_per_eval": peer["us_per_eval"] / mine["us_per_eval"],
            "our_cost": mine["cost"],
            "their_cost": peer["cost"],
        }
    result["ratios"] = ratios
    # (c) thesis table 5: 10 runs of BA and RSBA, 500 iterations, 100 bats.
    seeds = range(10)
    ba = [ours(obj, lo, hi, "ba", s, iterations=500)["cost"] for s in seeds]
    rsba = [ours(obj, lo, hi, "rsba", s, iterations=500)["cost"] for s in seeds]
    result["ba_vs_rsba_500"] = {"ba": ba, "rsba": rsba, "median_ba": float(np.median(ba)),
                                "median_rsba": float(np.median(rsba))}
    errs = []
    for s in seeds:
        cal = calibrate(model, series, gh, make_algorithm("rsba", iterations=2500), seed=s)
        errs.append(max(abs(cal.params[k] - v) / v for k, v in ASSUMED.items()) * 100)
    result["rsba_2500_max_relative_error_percent"] = errs
    result["summary"] = {
        "thesis_task_seconds": {k: round(v["seconds"], 3) for k, v in thesis.items()},
        "speedup_per_eval_vs_peers": {k: round(v["speedup_per_eval"], 1) for k, v in ratios.items()},
        "cost_ours_vs_peers": {k: [v["our_cost"], v["their_cost"]] for k, v in ratios.items()},
        "median_final_cost_500_it": {"ba": float(np.median(ba)), "rsba": float(np.median(rsba))},
        "rsba_2500_worst_param_error_percent_median": float(np.median(errs)),
    }
    return result


def thesis_round() -> dict[str, float]:
    """One process's figure for ``--against``: the thesis task with RIWPSO, best of ROUNDS CPU
    times [s] (the same seed, so the same cost each time)."""
    _, _, _, obj, lo, hi = _problem()
    best, cost = float("inf"), float("nan")
    for _ in range(ROUNDS):
        c0 = time.process_time()
        cost = ours(obj, lo, hi, "riwpso", seed=0)["cost"]
        best = min(best, time.process_time() - c0)
    return {"cpu_s": best, "cost": float(cost)}


def run_against(ref: str) -> dict:
    """(a) with RIWPSO, this tree against ``ref``'s code, interleaved (module docstring)."""
    base, this = against(__file__, ref, AGAINST_ROUNDS)
    ratios = [t["cpu_s"] / b["cpu_s"] for b, t in zip(base, this, strict=True)]
    return {"ref": ref, "rounds": {"this": this, ref: base},
            "summary": {"thesis_task_cpu_s_this": [round(t["cpu_s"], 3) for t in this],
                        f"thesis_task_cpu_s_at_{ref}": [round(b["cpu_s"], 3) for b in base],
                        f"this_over_{ref}_median_of_rounds": float(np.median(ratios)),
                        "same_final_cost": all(b["cost"] == t["cost"]
                                               for b, t in zip(base, this, strict=True))}}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--against", metavar="REF",
                        help="only the thesis task, this tree against this git commit's code")
    parser.add_argument("--round", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.round:  # one round in this process, JSON on the last line (used by --against)
        print(json.dumps(thesis_round()))
    elif args.against:
        result = run_against(args.against)
        print(write_result("calibration_against", result))
        print(json.dumps(result["summary"], indent=2))
    else:
        print(write_result("calibration", run()))

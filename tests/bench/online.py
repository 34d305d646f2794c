"""Online estimator bench: time per step and peak memory, vectorised RSBA vs a per-bat loop.

The ``almeria`` model with the thesis settings (§IV.2.2.2): 20 bats, air temperature every step
on the last n = 3 samples (all nine temperature parameters, gated by activity), radiation
sub-model every 20 steps on n = 60; 50 RSBA iterations (online.DEFAULT_ITERATIONS: the error
does not improve with 100, docs/online-estimator.md). Data: one day of the reference simulator
(almeria plant, synthetic Almería spring weather), fed sample by sample as the gateway does.

(a) vectorised: ``swarm.bat`` evaluates the 20 bats in one call per iteration (the shipped code);
(b) per-bat loop: the same RSBA written as the MATLAB original would run it, one virtual-model
    run per bat per iteration, on the first ``LOOP_SAMPLES`` daytime samples (it is ~10x slower).
Thesis figure: 2.04 s per step (MATLAB, i7-4810MQ). Goal: median ≤ 20 ms on one core.
"""

from __future__ import annotations

import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # not tests/bench/gateway.py
from _common import no_arguments, one_core, write_result  # noqa: E402

one_core()

import numpy as np  # noqa: E402

from gateway.estimate.online import DEFAULT_ITERATIONS, OnlineEstimator, online_settings  # noqa: E402
from gateway.estimate.swarm import BatSettings, SearchResult, _redraw_outside, _to_raw, _to_unit  # noqa: E402
from gateway.greenhouse import load_greenhouse  # noqa: E402
from gateway.model import build_model  # noqa: E402
from gateway.series import Series  # noqa: E402

THESIS_MS = 2040.0
LOOP_SAMPLES = 120
LOOP_START = 8 * 60  # 08:00, sun up and vents about to open: every parameter active


def rsba_per_bat(cost, lower, upper, s: BatSettings, variant="rsba", rng=None, x0=None, progress=None):
    """RSBA (III.40–III.46 with III.44–III.45) with one cost call per bat: same algorithm and
    random draws per bat as ``swarm.bat``, written as a plain loop."""
    rng = rng or np.random.default_rng()
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    n, k = s.bats, len(lower)
    u = rng.random((n, k))
    if x0 is not None:
        u[0] = _to_unit(np.asarray(x0, float), lower, upper)
    v = np.zeros((n, k))
    fit = np.array([float(cost(_to_raw(u[i], lower, upper)[None, :])[0]) for i in range(n)])
    loud = np.full(n, s.loudness)
    rate = np.zeros(n)
    g = int(np.argmin(fit))
    best_u, best_cost = u[g].copy(), float(fit[g])
    sigma = s.sigma_max
    for it in range(1, s.iterations + 1):
        for i in range(n):
            f = s.f_min + (s.f_max - s.f_min) * rng.random()
            v[i] = v[i] + (u[i] - best_u) * f
            new = u[i] + v[i]
            if rng.random() > rate[i]:
                new = best_u + sigma * rng.uniform(-1.0, 1.0, k)
            new = _redraw_outside(new, rng)
            c = float(cost(_to_raw(new, lower, upper)[None, :])[0])
            c = c if np.isfinite(c) else np.inf
            if c <= fit[i] and rng.random() < loud[i]:
                u[i], fit[i] = new, c
                loud[i] *= s.alpha
                rate[i] = s.r0 * (1.0 - np.exp(-s.gamma * it))
            if c <= best_cost:
                best_u, best_cost = new.copy(), c
        sigma = s.sigma_min + (s.sigma_max - s.sigma_min) * rng.random()
    best = _to_raw(best_u, lower, upper)
    return SearchResult(best, best_cost, np.array([best_cost]), n * (s.iterations + 1), s.iterations)


def _data() -> tuple[Series, list[dict[str, float]]]:
    from training.simulate import simulate

    r = simulate(plant="almeria", weather="almeria", start="2020-03-27", days=1, seed=1)
    series = Series(r.time, 60.0, {k: np.asarray(v, float) for k, v in r.columns.items()})
    rows = [{k: float(v[t]) for k, v in series.columns.items()} for t in range(len(series))]
    return series, rows


def _time_steps(est: OnlineEstimator, rows: list[dict[str, float]]) -> np.ndarray:
    """(steps, 2): wall time and CPU time of this process per ``update`` [ms]. On a shared
    machine the wall time includes waiting for the core; the CPU time does not."""
    out = np.empty((len(rows), 2))
    for i, row in enumerate(rows):
        w0, c0 = time.perf_counter_ns(), time.process_time_ns()
        est.update(row)
        out[i] = ((time.perf_counter_ns() - w0) / 1e6, (time.process_time_ns() - c0) / 1e6)
    return out


def _stats(ms: np.ndarray) -> dict[str, dict[str, float] | int]:
    def one(v):
        return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}

    return {"wall": one(ms[:, 0]), "cpu": one(ms[:, 1]), "steps": int(len(ms))}


def run() -> dict:
    gh = load_greenhouse("almeria-palmerillas")
    model = build_model("almeria", gh)
    settings = online_settings(model, gh)
    theta0 = model.defaults(gh)
    series, rows = _data()
    load_before = os.getloadavg()
    # (a) the whole day, vectorised
    est = OnlineEstimator(model, gh, theta0, settings)
    day = _time_steps(est, rows)
    # (a') and (b) on the same daytime stretch, same warm-up
    warm = rows[LOOP_START - 61 : LOOP_START]
    sub = rows[LOOP_START : LOOP_START + LOOP_SAMPLES]
    vec = OnlineEstimator(model, gh, theta0, settings)
    _time_steps(vec, warm)
    vec_ms = _time_steps(vec, sub)
    loop = OnlineEstimator(model, gh, theta0, settings, search=rsba_per_bat)
    _time_steps(loop, warm)
    loop_ms = _time_steps(loop, sub)
    # peak memory: Python allocations of a fresh estimator over 200 samples, and the process RSS
    tracemalloc.start()
    mem = OnlineEstimator(model, gh, theta0, settings)
    _time_steps(mem, rows[LOOP_START : LOOP_START + 200])
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    summary = {
        "model": "almeria",
        "settings": "20 bats; t_in n=3 every 1; i_in n=60 every 20",
        "iterations": DEFAULT_ITERATIONS,
        "vectorised_day_ms": _stats(day),
        "vectorised_daytime_ms": _stats(vec_ms),
        "per_bat_loop_daytime_ms": _stats(loop_ms),
        "loop_over_vectorised_cpu": float(np.median(loop_ms[:, 1]) / np.median(vec_ms[:, 1])),
        "thesis_ms": THESIS_MS,
        "speedup_vs_thesis_median_wall": float(THESIS_MS / np.median(day[:, 0])),
        "speedup_vs_thesis_median_cpu": float(THESIS_MS / np.median(day[:, 1])),
        "goal_median_ms": 20.0,
        "peak_python_alloc_mb": peak / 2**20,
        "peak_rss_mb": rss_mb,
        "load_average_1min_before": load_before[0],
        "load_average_1min_after": os.getloadavg()[0],
    }
    return {"summary": summary}


if __name__ == "__main__":
    no_arguments(__doc__, "online")
    result = run()
    path = write_result("online", result)
    import json

    print(json.dumps(result["summary"], indent=2))
    print(f"wrote {path}")

"""What ``python -m gateway replay`` costs on 1-minute data: one fixed simulated day (the reference
simulator's Almería house on its synthetic spring weather, seed 2, the kit's six columns at 60 s
rows, the generality suite's greenhouse file for it), replayed with ``prototype`` and
``prototype+vent_control`` (the live default) as the CLI does (``replay``, ``report``,
``write_predictions``), on one core, in CPU time.

``--against REF`` (a git commit or branch) also measures the code of REF, exported by
``git archive`` to a temporary folder: each round runs one process on REF's tree and one on this
tree, alternately, and the summary adds the median of the rounds' ratios this tree / REF. Each
round also gives a digest of everything the replay wrote (the predictions CSV and the report
without its wall-clock ``step_ms``), so the JSON says whether the two trees' results are the same
bit for bit. ``score_cpu_s`` is the scoring after the estimator's loop alone (``score_forecasts``,
run again on the replay's record), with its own ratio in the summary. Run it under ``nice`` on a
shared machine (docs/online-estimator.md, "Replay speed").
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time
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

MODELS = ("prototype", "prototype+vent_control")
KIT = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind")
ROUNDS = 2


def _day():
    """The fixed day: (series, greenhouse)."""
    from gateway.greenhouse import parse_greenhouse
    from gateway.series import Series
    from training.simulate import simulate

    r = simulate(plant="almeria", weather="almeria", start="2020-03-01", days=1, seed=2)
    series = Series(r.time, 60.0, {k: np.asarray(r.columns[k], float) for k in KIT})
    gh = parse_greenhouse({"name": "refsim-almeria",
                           "geometry": {"floor_area": 877.0, "volume": 877.0 * 3.5},
                           "site": {"latitude": 36.79, "longitude": -2.72}}, "<bench replay>")
    return series, gh


def _one(name: str, series, gh, folder: str) -> dict:
    """One replay as the CLI runs it: CPU seconds of each part and the digest of its results."""
    from gateway.estimate.online import online_settings
    from gateway.estimate.replay import replay, report, write_predictions
    from gateway.model import build_model

    model = build_model(name, gh)
    c0 = time.process_time()
    result = replay(model, series, gh, None, online_settings(model, gh), seed=0)
    c1 = time.process_time()
    rep = report(result)
    path = Path(folder) / f"{name}.csv"
    write_predictions(result, path)
    c2 = time.process_time()
    rep.pop("step_ms")  # wall clock: the one field that differs from run to run
    digest = hashlib.sha256(path.read_bytes() + json.dumps(rep, sort_keys=True).encode())
    return {"cpu_s": c2 - c0, "replay_cpu_s": c1 - c0, "score_cpu_s": _score_cpu(result),
            "rows": len(series), "ms_per_row": 1e3 * (c2 - c0) / len(series),
            "digest": digest.hexdigest()[:16]}


def _score_cpu(result) -> float:
    """CPU seconds of the scoring after the loop alone (``score_forecasts``: the ARX, the
    disturbance filter, the forecasts, their combination and correction), run again on a copy
    of the replay's record (not counted in ``cpu_s``)."""
    from dataclasses import replace

    from gateway.estimate.replay import HORIZONS, score_forecasts, steps_of

    again = replace(result, horizons={})
    c0 = time.process_time()
    score_forecasts(again, steps_of(HORIZONS, result.dt))
    return time.process_time() - c0


def _round() -> dict:
    series, gh = _day()
    with tempfile.TemporaryDirectory(prefix="serra-bench-replay-") as folder:
        return {name: _one(name, series, gh, folder) for name in MODELS}


def run(against: str | None = None, rounds: int = ROUNDS) -> dict:
    if against is None:
        this, base = [_round() for _ in range(rounds)], None
    else:
        base, this = against_rounds(__file__, against, rounds)
    summary: dict = {"cpu_s_median_of_rounds": {
        m: float(np.median([r[m]["cpu_s"] for r in this])) for m in MODELS}}
    out: dict = {"rounds": this, "summary": summary}
    if base is not None:
        summary[f"cpu_s_median_of_rounds_at_{against}"] = {
            m: float(np.median([r[m]["cpu_s"] for r in base])) for m in MODELS}
        summary[f"this_over_{against}_median_of_rounds"] = {
            m: float(np.median([t[m]["cpu_s"] / b[m]["cpu_s"] for t, b in zip(this, base, strict=True)]))
            for m in MODELS}
        summary[f"score_this_over_{against}_median_of_rounds"] = {
            m: float(np.median([t[m]["score_cpu_s"] / b[m]["score_cpu_s"]
                                for t, b in zip(this, base, strict=True)]))
            for m in MODELS}
        summary["same_results_as_base"] = all(
            t[m]["digest"] == b[m]["digest"] for t, b in zip(this, base, strict=True) for m in MODELS)
        out[f"rounds_at_{against}"] = base
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--against", metavar="REF", help="also measure this git commit's code")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help=f"rounds ({ROUNDS})")
    parser.add_argument("--round", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.round:  # one round in this process, JSON on the last line (used by --against)
        print(json.dumps(_round()))
        raise SystemExit(0)
    result = run(args.against, args.rounds)
    print(write_result("replay", result))
    print(json.dumps(result["summary"], indent=2))

"""The forecast part of the generality suite alone: ``replay`` on the effect-free windows.

Runs the suite's forecast cases (tests/generality/cases.py: each generator's kit data, 5-minute
rows, the live default model ``prototype+vent_control`` (``--model prototype``: the
four-parameter one), day 1 left out as the estimator's warm-up) and tabulates the 15/30/60-min
MAE of persistence, the RLS ARX, the adaptive model and the adaptive model with the disturbance
filter (gateway/estimate/disturbance.py), each with the weather later measured and with the
causal outlook. Writes ``bench/results/forecasts.json`` and prints the Markdown table of
docs/online-estimator.md ("Forecasts on greenhouses we did not build").

    nice -n 5 .venv/bin/python tests/generality/forecasts.py [--jobs 2]
        [--generators refsim,twonode,vanthoor] [--windows autumn,winter,summer] [--keep DIR]
        [--model prototype]    # default prototype+vent_control (the live gateway's default)
    .venv/bin/python tests/generality/forecasts.py --rescore DIR   # the forecasts again, no replay
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.model import PROTOTYPES  # noqa: E402
from tests.generality.cases import FORECAST_MODEL, Case, run  # noqa: E402
from tests.generality.generators import GENERATORS, HELD_OUT  # noqa: E402
from tests.generality.report import MAIN_WINDOWS, goals  # noqa: E402
from tests.generality.suite import commit_id, init_worker  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "forecasts.json"
COLUMNS = (("persistence", "persistence"), ("arx", "ARX"), ("adaptive", "adaptive"),
           ("adaptive_kf", "adaptive + KF"), ("combined", "combined"), ("corrected", "corrected"),
           ("arx_outlook", "ARX, outlook"), ("adaptive_outlook", "adaptive, outlook"),
           ("adaptive_kf_outlook", "adaptive + KF, outlook"), ("combined_outlook", "combined, outlook"),
           ("corrected_outlook", "corrected, outlook"))
"""(report key, table heading), in the table's order."""


NAMES = ("adaptive", "adaptive_kf", "combined", "corrected")
"""The forecasts whose goals are marked (each with its ``_outlook`` twin)."""


def markdown(results: list[dict]) -> str:
    mark = {True: "✓", False: "✗", None: ""}
    head = [c[1] for c in COLUMNS]
    lines = ["| generator | window | h [min] | " + " | ".join(head)
             + " | goal, measured (adaptive / + KF / combined / corrected) | goal, outlook (same) |",
             "| --- " * (len(head) + 5) + "|"]
    order = {g: i for i, g in enumerate(GENERATORS)}
    for r in sorted(results, key=lambda r: (order[r["case"]["generator"]],
                                            MAIN_WINDOWS.index(r["case"]["window"]))):
        g, w = r["case"]["generator"], r["case"]["window"]
        label = f"{g} (held out)" if g in HELD_OUT else g
        if "error" in r:
            lines.append(f"| {label} | {w} | error: {r['error']} |")
            continue
        for minutes, h in r["horizons"].items():
            cells = [f"{h[k]['mae']:.3f}" for k, _ in COLUMNS]
            marks = [goals(h, name, int(minutes)) for name in NAMES]
            lines.append(f"| {label} | {w} | {minutes} | " + " | ".join(cells)
                         + " | " + " / ".join(mark[m] for m, _ in marks)
                         + " | " + " / ".join(mark[o] for _, o in marks) + " |")
    return "\n".join(lines) + "\n"


def _label(r: dict) -> str:
    return f"{r['case']['generator']} {r['case']['window']}"


def summary(results: list[dict]) -> str:
    """Per window (all three horizons), for each marked forecast: on how many windows it beats
    the ARX at every horizon, is ≥ 30 % better than persistence at every horizon, meets the
    measured-weather goal and the outlook goal; the held-out generator counted apart."""
    order = {g: i for i, g in enumerate(GENERATORS)}
    ok = sorted((r for r in results if "error" not in r),
                key=lambda r: (order[r["case"]["generator"]], MAIN_WINDOWS.index(r["case"]["window"])))
    held = sum(r["case"]["generator"] in HELD_OUT for r in ok)
    lines = ["| forecast | beats the ARX at every horizon | ≥ 30 % better than persistence at "
             "every horizon | measured-weather goal | outlook goal (≥ 20 % at 30 and 60) |",
             "| --- | --- | --- | --- | --- |"]
    for name in NAMES:
        sets: list[list[str]] = [[], [], [], []]
        for r in ok:
            hs = r["horizons"]
            tests = (all(h[name]["mae"] < h["arx"]["mae"] for h in hs.values()),
                     all(h[name]["mae"] <= 0.7 * h["persistence"]["mae"] for h in hs.values()),
                     all(goals(h, name, int(m))[0] for m, h in hs.items()),
                     all(goals(h, name, int(m))[1] is not False for m, h in hs.items()))
            for k, passed in enumerate(tests):
                if passed:
                    sets[k].append(r)
        cells = []
        for s in sets:
            h = sum(r["case"]["generator"] in HELD_OUT for r in s)
            where = "; ".join(_label(r) for r in s)
            cells.append(f"{len(s)} / {len(ok)} (held out {h} / {held})" + (f": {where}" if where else ""))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def rescore(folder: Path, blocks: Callable | None = None) -> list[dict]:
    """The cases again from the replays pickled by ``--keep``: the estimator's loop is not run,
    everything after it (ARX, filter, forecasts, report) is, with the code as it is now. The
    outlook's driver blocks are the kept ones (``res.ahead``) unless ``blocks(res)`` makes new
    ones (an outlook changed since: the loop never reads the outlook, so this is what a whole
    replay with it gives; tests/generality/outlook_costs.py)."""
    import pickle

    from gateway.estimate.replay import HORIZONS, score_forecasts, steps_of
    from tests.generality.cases import forecast_report

    results = []
    for f in sorted(folder.glob("*.pkl")):
        generator, window = f.stem.split("-", 1)
        res = pickle.loads(f.read_bytes())
        t0 = time.perf_counter()
        if blocks is not None:
            res.ahead = blocks(res)
        score_forecasts(res, steps_of(HORIZONS, res.dt))
        case = Case("forecast", generator, window, model=res.model.name)
        results.append({"case": asdict(case), **forecast_report(res),
                        "seconds": time.perf_counter() - t0})
    return results


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="parallel processes (2)")
    ap.add_argument("--generators", default=",".join(GENERATORS))
    ap.add_argument("--windows", default=",".join(MAIN_WINDOWS))
    ap.add_argument("--model", default=FORECAST_MODEL, choices=PROTOTYPES,
                    help=f"the replayed model ({FORECAST_MODEL}, the live default; prototype: the "
                    "four-parameter model without gateway/model/vent_control.py; "
                    "prototype+vent_control+heating: with a thermostat-run heater, opt-in)")
    ap.add_argument("--json", default=str(RESULTS), help=f"results file ({RESULTS.relative_to(ROOT)})")
    ap.add_argument("--keep", metavar="DIR", help="also pickle each replay into DIR (to study the "
                    "forecasts without replaying again)")
    ap.add_argument("--rescore", metavar="DIR", help="run no replay: score the replays pickled in "
                    "DIR by --keep again with the current forecast code")
    a = ap.parse_args(argv)
    gens = [g for g in a.generators.split(",") if g]
    if bad := [g for g in gens if g not in GENERATORS]:
        ap.error(f"unknown generator(s) {bad}; known: {', '.join(GENERATORS)}")
    wins = [w for w in a.windows.split(",") if w]
    if bad := [w for w in wins if w not in MAIN_WINDOWS]:
        ap.error(f"unknown window(s) {bad}; known: {', '.join(MAIN_WINDOWS)}")
    cases = [Case("forecast", g, w, model=a.model) for g in gens for w in wins]
    t0 = time.perf_counter()
    if a.rescore:
        results = [r for r in rescore(Path(a.rescore))
                   if r["case"]["generator"] in gens and r["case"]["window"] in wins]
    else:
        print(f"forecast replays: {len(cases)} cases on {a.jobs} processes", flush=True)
        results = []
        with mp.get_context("spawn").Pool(a.jobs, initializer=init_worker) as pool:
            for i, r in enumerate(pool.imap_unordered(partial(run, keep=a.keep), cases), 1):
                results.append(r)
                print(f"[{i}/{len(cases)}] {Case(**r['case']).label} ({r['seconds']:.0f} s)",
                      flush=True)
    meta = {"command": "tests/generality/forecasts.py" + (" --rescore" if a.rescore else ""),
            "cases": len(results), "jobs": None if a.rescore else a.jobs,  # a rescore runs none
            "minutes": (time.perf_counter() - t0) / 60.0, "commit": commit_id(),
            "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    out = Path(a.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out}\n")
    print(markdown(results))
    print(summary(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

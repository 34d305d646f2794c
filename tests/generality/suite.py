"""``make bench-generality``: the generality suite, every case in parallel processes.

Three generators (tests/generality/generators.py; ``vanthoor`` held out) × the autumn, winter
and summer windows × every change kind (7 in the diagnosis library, 2 outside it), plus 10
effect-free windows per generator, each diagnosed with the kit's prototype model; and the
forecast replay (measured weather and the causal outlook, beside persistence and the RLS ARX)
on each generator's three main windows. Writes ``bench/results/generality.json`` and the
Markdown section of docs/effects.md (between its markers).

    python tests/generality/suite.py [--jobs 2] [--generators refsim,twonode,vanthoor]
        [--only diagnose|forecast] [--windows autumn,winter] [--no-docs] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import EXTRA_WINDOWS, FORECAST_MODEL, MODEL, Case, run  # noqa: E402
from tests.generality.generators import GENERATORS, HELD_OUT, KINDS, OUTSIDE  # noqa: E402
from tests.generality.report import MAIN_WINDOWS, markdown, update_docs  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "generality.json"
DOCS = ROOT / "docs" / "effects.md"
BEFORE = ROOT / "docs" / "generality-before.json"


ALL_KINDS = ("none", *KINDS, *OUTSIDE)


def all_cases(generators=GENERATORS, windows=MAIN_WINDOWS, only: str | None = None,
              kinds=ALL_KINDS, seed: int = 1) -> list[Case]:
    """Slowest first (forecast replays), so the processes finish together. ``seed``: the
    generators' sensor noise and biases (and the visible-size reference, same seed)."""
    cases = []
    if only in (None, "forecast"):
        cases += [Case("forecast", g, w, seed=seed, model=FORECAST_MODEL)
                  for g in generators for w in windows]
    if only in (None, "diagnose"):
        for g in generators:
            cases += [Case("diagnose", g, w, k, seed) for w in windows for k in kinds]
            if tuple(windows) == MAIN_WINDOWS and "none" in kinds:
                cases += [Case("diagnose", g, w, seed=seed) for w in EXTRA_WINDOWS]
    return cases


def init_worker(day_weights: bool = False) -> None:
    """One thread per worker; the judge's ``DAY_WEIGHTS`` as asked (``--day-weights``)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    if day_weights:
        from gateway.diagnose import judge

        judge.DAY_WEIGHTS = True


def _line(r: dict) -> str:
    if "error" in r:
        return f"ERROR {r['error']}"
    if r["case"]["task"] == "forecast":
        h = r["horizons"].get("60", {})
        return "60 min MAE " + ", ".join(f"{k} {v['mae']:.3f}" for k, v in h.items() if v)
    first = r["findings"][0]["effect"] if r["findings"] else "none"
    return f"first {first}, MAE {r['before']:.3f} → {r['after']:.3f}, ok {r['verdict']['ok']}"


def commit_id() -> str:
    try:
        return subprocess.check_output(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                       text=True).strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="parallel processes (2)")
    ap.add_argument("--generators", default=",".join(GENERATORS), metavar="G,G",
                    help=f"comma-separated generators ({','.join(GENERATORS)}; "
                    f"{','.join(sorted(HELD_OUT))} is held out: reported apart)")
    ap.add_argument("--windows", default=",".join(MAIN_WINDOWS),
                    help=f"main windows (the {len(EXTRA_WINDOWS)} extra effect-free ones run only "
                    "with all three)")
    ap.add_argument("--only", choices=["diagnose", "forecast"],
                    help="run only the diagnosis cases or only the forecast rows (both)")
    ap.add_argument("--kinds", default=",".join(ALL_KINDS), help="changes to diagnose (all)")
    ap.add_argument("--seed", type=int, default=1,
                    help="the generators' noise seed, every case (1: the suite's usual results)")
    ap.add_argument("--json", default=str(RESULTS), help=f"results file ({RESULTS.relative_to(ROOT)})")
    ap.add_argument("--no-docs", action="store_true", help="do not rewrite docs/effects.md")
    ap.add_argument("--merge", action="store_true",
                    help="keep the other cases of an existing results file (rerun a part only)")
    ap.add_argument("--day-weights", action="store_true",
                    help="judge with the day test weighted by each candidate's own predicted "
                    "change (judge.DAY_WEIGHTS; off as shipped)")
    ap.add_argument("--combine", nargs="+", metavar="RESULTS.json",
                    help="run nothing: join these results files (later ones win) into --json and docs")
    a = ap.parse_args(argv)
    gens = tuple(g for g in a.generators.split(",") if g)
    bad = [g for g in gens if g not in GENERATORS]
    if bad:
        ap.error(f"unknown generator(s) {bad}; known: {', '.join(GENERATORS)}")
    if a.combine:
        return _combine([Path(f) for f in a.combine], Path(a.json), not a.no_docs)
    kinds = tuple(k for k in a.kinds.split(",") if k)
    unknown = [k for k in kinds if k not in ALL_KINDS]
    if unknown:
        ap.error(f"unknown change(s) {unknown}; known: {', '.join(ALL_KINDS)}")
    cases = all_cases(gens, tuple(a.windows.split(",")), a.only, kinds, a.seed)
    print(f"generality suite: {len(cases)} cases on {a.jobs} processes", flush=True)
    t0 = time.perf_counter()
    results = []
    ctx = mp.get_context("spawn")  # a clean interpreter per worker: no state shared with the parent
    with ctx.Pool(a.jobs, initializer=init_worker, initargs=(a.day_weights,),
                  maxtasksperchild=4) as pool:
        for i, r in enumerate(pool.imap_unordered(run, cases), 1):
            results.append(r)
            spent = time.perf_counter() - t0
            eta = spent / i * (len(cases) - i)
            label = Case(**r["case"]).label
            print(f"[{i:3d}/{len(cases)}] {label}: {_line(r)} ({r['seconds']:.0f} s; "
                  f"elapsed {spent / 60:.1f} min, ~{eta / 60:.0f} min left)", flush=True)
    minutes = (time.perf_counter() - t0) / 60.0
    out = Path(a.json)
    if a.merge and out.exists():
        done = {Case(**r["case"]) for r in results}
        old = json.loads(out.read_text(encoding="utf-8"))
        kept = [r for r in old["results"] if Case(**r["case"]) not in done]
        results = kept + results
        minutes += old["meta"].get("minutes", 0.0)
    meta = {"command": "make bench-generality", "cases": len(results), "jobs": a.jobs,
            "minutes": minutes, "runs": [{"minutes": minutes, "jobs": a.jobs}],
            "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": commit_id(),
            "model": MODEL, "forecast_model": FORECAST_MODEL, "generators": list(gens), "seed": a.seed,
            "day_weights": a.day_weights}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out} in {minutes:.1f} min", flush=True)
    if not a.no_docs:
        update_docs(DOCS, markdown(results, meta, _before()))
        print(f"updated {DOCS.relative_to(ROOT)}", flush=True)
    return 0


def _before() -> dict | None:
    """The run before issue 10's base and judge work, shown beside (docs/generality-before.json)."""
    return json.loads(BEFORE.read_text(encoding="utf-8")) if BEFORE.exists() else None


def _combine(files: list[Path], out: Path, docs: bool) -> int:
    by_case: dict[Case, dict] = {}
    minutes = 0.0
    runs: list[dict] = []
    for f in files:
        data = json.loads(f.read_text(encoding="utf-8"))
        minutes += data["meta"].get("minutes", 0.0)
        runs += data["meta"].get("runs") or [{"minutes": data["meta"].get("minutes", 0.0),
                                               "jobs": data["meta"].get("jobs") or 1}]
        for r in data["results"]:
            by_case[Case(**r["case"])] = r
    results = list(by_case.values())
    meta = {**data["meta"], "cases": len(results), "minutes": minutes, "runs": runs,
            "combined": [str(f) for f in files]}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out} ({len(results)} cases)", flush=True)
    if docs:
        update_docs(DOCS, markdown(results, meta, _before()))
        print(f"updated {DOCS.relative_to(ROOT)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

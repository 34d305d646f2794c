"""Study: the diagnosis on kit-sensor data from two generators and several weather windows.

Writes one JSON line per case (``--out``, default bench/results/diagnosis_study.jsonl) and
prints a Markdown summary (``--summary`` reads an existing file). Cases are listed in
docs/effects.md, "Generality"; the data come from tests.generality.diagnosis_cases.py.

    python tests/generality/diagnosis_study.py --set effects      # 2 generators x 3 windows x 8 cases
    python tests/generality/diagnosis_study.py --set null         # 2 generators x 10 effect-free windows
    python tests/generality/diagnosis_study.py --summary bench/results/diagnosis_study.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.generality.diagnosis_cases import (  # noqa: E402
    EFFECT_FREE_WINDOWS,
    EXPECTED,
    KINDS,
    make_case,
)

WINDOWS = ("autumn", "winter", "summer")


def _read(path: str) -> list[dict]:
    return [json.loads(s) for s in Path(path).read_text().splitlines() if s.strip()]


def jobs(which: str, generators, plants) -> list[tuple[str, str, str, str]]:
    out = []
    for gen in generators:
        for plant in plants:
            if which in ("effects", "all"):
                for w in WINDOWS:
                    for kind in (*KINDS, "none", "misting"):
                        out.append((gen, plant, w, kind))
            if which in ("null", "all"):
                for w in EFFECT_FREE_WINDOWS:
                    if which == "all" and w in WINDOWS:
                        continue
                    out.append((gen, plant, w, "none"))
    return out


def run_one(gen: str, plant: str, window: str, kind: str, seed: int) -> dict:
    from gateway.diagnose import diagnose
    from gateway.model import build_model

    case = make_case(gen, plant, EFFECT_FREE_WINDOWS[window](), kind, seed=seed)
    model = build_model("prototype", case.gh)
    t0 = time.perf_counter()
    d = diagnose(case.series, case.gh, model)
    seconds = time.perf_counter() - t0
    first = d.findings[0] if d.findings else None
    err_h = None
    if first is not None and first.start and case.start is not None:
        err_h = float((np.datetime64(first.start.rstrip("Z")) - case.start)
                      / np.timedelta64(1, "s")) / 3600.0
    before, after = d.before["free_run"]["mae"], d.after["free_run"]["mae"]
    return {
        "generator": gen, "plant": plant, "window": window, "kind": kind, "seed": seed,
        "truth_start": None if case.start is None else str(case.start),
        "findings": [{"effect": f.effect.name, "start": f.start, "amplitude": f.amplitude,
                      "summary": f.summary, "evidence": f.evidence} for f in d.findings],
        "named": bool(first is not None and kind in EXPECTED
                      and first.effect.name in EXPECTED[kind]),
        "start_error_h": err_h,
        "mae_before": before, "mae_after": after, "cut": 1.0 - after / before,
        "persistence_mae": d.persistence["free_run"]["mae"],
        "one_step_before": d.before["one_step"]["mae"],
        "unexplained": bool(d.unexplained), "signature": d.signature,
        "structure": [s["structure"] for s in d.structure if s["kept"]],
        "rejected": [{k: v for k, v in r.items() if k in ("effect", "reason")}
                     for r in d.rejected],
        "trials": getattr(d, "trials", []),
        "seconds": seconds,
    }


def summary(rows: list[dict]) -> str:
    lines = ["| generator | plant | window | case | first finding (start error) | held-out "
             "free-run MAE before → after (cut) | persistence | unexplained |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        f = r["findings"][0] if r["findings"] else None
        name = "none" if f is None else f"`{f['effect']}`"
        if f is not None and r["start_error_h"] is not None:
            name += f" ({r['start_error_h']:+.1f} h)"
        ok = ""
        if r["kind"] in EXPECTED:
            ok = " ✓" if r["named"] and abs(r["start_error_h"] or 99) <= 12 and r["cut"] >= 0.2 else " ✗"
        elif r["kind"] == "none":
            ok = " ✓" if f is None else " ✗"
        lines.append(f"| {r['generator']} | {r['plant']} | {r['window']} | {r['kind']} | {name}{ok} "
                     f"| {r['mae_before']:.3f} → {r['mae_after']:.3f} ({-100 * r['cut']:+.0f} %) "
                     f"| {r['persistence_mae']:.3f} | {'yes' if r['unexplained'] else 'no'} |")
    return "\n".join(lines)


def _ok(r: dict) -> bool:
    """The issue-10 target for one effect case: named first, start within 12 h, cut ≥ 20 %
    (significance: the finding passed the judge)."""
    return bool(r["named"] and r["start_error_h"] is not None and abs(r["start_error_h"]) <= 12
                and r["cut"] >= 0.2)


def scorecard(rows: list[dict]) -> str:
    """Per generator and window: effect kinds meeting the target, effect-free runs with no
    finding, the change outside the library flagged unexplained."""
    lines = ["| generator | plant | window | effect kinds met (of 6) | effect-free: no finding | "
             "misting: unexplained |", "| --- | --- | --- | --- | --- | --- |"]
    keys = sorted({(r["generator"], r["plant"], r["window"]) for r in rows},
                  key=lambda k: (k[0], k[1], WINDOWS.index(k[2]) if k[2] in WINDOWS else 9, k[2]))
    for key in keys:
        rs = [r for r in rows if (r["generator"], r["plant"], r["window"]) == key]
        eff = [r for r in rs if r["kind"] in EXPECTED]
        met = [r["kind"] for r in eff if _ok(r)]
        none = [r for r in rs if r["kind"] == "none"]
        mist = [r for r in rs if r["kind"] == "misting"]
        lines.append(
            f"| {key[0]} | {key[1]} | {key[2]} | "
            + (f"{len(met)} ({', '.join(met)})" if eff else "–") + " | "
            + (("yes" if not none[0]["findings"] else "**no**: " + none[0]["findings"][0]["effect"])
               if none else "–") + " | "
            + (("yes" if mist[0]["unexplained"] and not mist[0]["findings"] else "**no**")
               if mist else "–") + " |")
    return "\n".join(lines)


def base_table(rows: list[dict], before: list[dict]) -> str:
    """Base held-out free-run MAE on effect-free data: before and after, beside persistence."""
    old = {(r["generator"], r["plant"], r["window"]): r for r in before if r["kind"] == "none"}
    lines = ["| generator | plant | window | base before [K] (kept parts) | base after [K] (kept "
             "parts) | persistence [K] | findings before → after |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if r["kind"] != "none":
            continue
        b = old.get((r["generator"], r["plant"], r["window"]))
        parts = lambda x: ", ".join(p.replace("long-wave ", "") for p in x["structure"][1:]) or "–"  # noqa: E731
        fb = (b["findings"][0]["effect"] if b and b["findings"] else "none") if b else "–"
        fa = r["findings"][0]["effect"] if r["findings"] else "none"
        lines.append(f"| {r['generator']} | {r['plant']} | {r['window']} | "
                     + (f"{b['mae_before']:.3f} ({parts(b)})" if b else "–")
                     + f" | {r['mae_before']:.3f} ({parts(r)}) | {r['persistence_mae']:.3f} | "
                     f"{fb} → {fa} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("effects", "null", "all"), default="all")
    ap.add_argument("--generators", default="refsim,twonode")
    ap.add_argument("--plants", default="box")
    ap.add_argument("--kinds", default=None, help="comma list to keep (default all)")
    ap.add_argument("--windows", default=None, help="comma list to keep (default all)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "diagnosis_study.jsonl"))
    ap.add_argument("--summary", metavar="JSONL", help="only print the tables of an existing file")
    ap.add_argument("--before", metavar="JSONL",
                    help="with --summary: the same study run on the code before, for the base table")
    a = ap.parse_args(argv)
    if a.summary:
        rows = _read(a.summary)
        print(scorecard(rows) + "\n\n" + summary(rows))
        if a.before:
            print("\n" + base_table(rows, _read(a.before)))
        return 0
    todo = jobs(a.set, a.generators.split(","), a.plants.split(","))
    if a.kinds:
        todo = [j for j in todo if j[3] in a.kinds.split(",")]
    if a.windows:
        todo = [j for j in todo if j[2] in a.windows.split(",")]
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    with out.open("a", encoding="utf-8") as fh:
        for i, (gen, plant, window, kind) in enumerate(todo, 1):
            r = run_one(gen, plant, window, kind, a.seed)
            rows.append(r)
            fh.write(json.dumps(r) + "\n")
            fh.flush()
            print(f"[{i}/{len(todo)}] {gen} {plant} {window} {kind}: "
                  f"{[f['effect'] for f in r['findings']]} {r['mae_before']:.3f}→"
                  f"{r['mae_after']:.3f} ({r['seconds']:.1f} s)", file=sys.stderr, flush=True)
    print(summary(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

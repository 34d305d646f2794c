"""Case-by-case comparison of two generality-suite diagnosis runs (suite.py ``--json``).

    python tests/generality/compare_diagnoses.py A.json B.json [--changed] [--kind thermal_mass]

For every diagnose case in both files: pass, false alarm, unexplained, first finding, start
error [h], base held-out free-run MAE [K] (``before``) and held-out cut, A → B. A case is marked
WORSE when B turns a pass into a fail, a quiet effect-free case into a finding (a false alarm)
or an unexplained case into one not flagged; BETTER for the reverse (and no WORSE). Cases in
one file only are listed at the end. The summary counts passes per change kind, the marks, and
the diagnoses' summed seconds (wall clock of the suite's workers: a rough CPU figure only).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

Key = tuple[str, str, str, int, str]


def load(path: str) -> dict[Key, dict]:
    """The diagnose rows of a suite JSON file by (generator, window, kind, seed, model)."""
    data = json.loads(Path(path).read_text())
    rows = data["results"] if isinstance(data, dict) else data
    out = {}
    for r in rows:
        c = r["case"]
        if c.get("task", "diagnose") != "diagnose":
            continue
        out[(c["generator"], c["window"], c["kind"], int(c.get("seed", 1)), c.get("model", ""))] = r
    return out


def facts(r: dict) -> dict:
    """What is compared of one case."""
    v = r.get("verdict") or {}
    first = r["findings"][0]["effect"] if r.get("findings") else None
    return {"ok": bool(v.get("ok")), "false_alarm": bool(v.get("false_alarm")),
            "unexplained": bool(r.get("unexplained")), "first": first or "none",
            "start_h": r.get("start_error_h"), "base": r.get("before"), "cut": r.get("cut"),
            "seconds": r.get("diagnosis_seconds") or 0.0, "error": r.get("error")}


def mark(a: dict, b: dict) -> str:
    """WORSE, BETTER or '' (module docstring)."""
    worse = ((a["ok"] and not b["ok"]) or (not a["false_alarm"] and b["false_alarm"])
             or (a["unexplained"] and not b["unexplained"]))
    if worse:
        return "WORSE"
    better = ((not a["ok"] and b["ok"]) or (a["false_alarm"] and not b["false_alarm"])
              or (not a["unexplained"] and b["unexplained"]))
    return "BETTER" if better else ""


def _num(v: float | None, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def _pair(a, b, fmt: str) -> str:
    return f"{_num(a, fmt)}→{_num(b, fmt)}"


def _yn(v: bool) -> str:
    return "y" if v else "n"


def table(A: dict[Key, dict], B: dict[Key, dict], changed: bool, kind: str | None) -> list[str]:
    head = (f"{'case':40s} {'pass':5s} {'f.alarm':7s} {'unexpl':6s} {'first finding':36s} "
            f"{'start err h':13s} {'base MAE K':13s} {'cut':13s} mark")
    lines = [head, "-" * len(head)]
    for key in sorted(set(A) & set(B)):
        if kind and key[2] != kind:
            continue
        a, b = facts(A[key]), facts(B[key])
        m = mark(a, b)
        same_first = a["first"] == b["first"]
        if changed and not m and same_first:
            continue
        label = "/".join(key[:3]) + ("" if key[3] == 1 else f" s{key[3]}")
        first = a["first"] if same_first else f"{a['first']}→{b['first']}"
        lines.append(
            f"{label:40s} {_yn(a['ok'])}→{_yn(b['ok']):2s} "
            f"{_yn(a['false_alarm'])}→{_yn(b['false_alarm']):4s} "
            f"{_yn(a['unexplained'])}→{_yn(b['unexplained']):3s} {first:36s} "
            f"{_pair(a['start_h'], b['start_h'], '+.1f'):13s} {_pair(a['base'], b['base'], '.3f'):13s} "
            f"{_pair(a['cut'], b['cut'], '+.2f'):13s} {m}")
    return lines


def summary(A: dict[Key, dict], B: dict[Key, dict]) -> list[str]:
    both = sorted(set(A) & set(B))
    marks = Counter(mark(facts(A[k]), facts(B[k])) for k in both)
    pa = Counter(k[2] for k in both if facts(A[k])["ok"])
    pb = Counter(k[2] for k in both if facts(B[k])["ok"])
    total = Counter(k[2] for k in both)
    sa = sum(facts(A[k])["seconds"] for k in both)
    sb = sum(facts(B[k])["seconds"] for k in both)
    out = [f"{len(both)} cases in both; WORSE {marks['WORSE']}, BETTER {marks['BETTER']}; "
           f"passes {sum(pa.values())} → {sum(pb.values())}",
           "passes per kind (A → B of n): " + ", ".join(
               f"{k} {pa[k]}→{pb[k]}/{total[k]}" for k in sorted(total)),
           f"diagnosis seconds summed: {sa:.0f} → {sb:.0f} (× {sb / max(sa, 1e-9):.2f}; wall "
           "clock of the suite's workers, not a CPU benchmark)"]
    for name, only in (("A", set(A) - set(B)), ("B", set(B) - set(A))):
        if only:
            out.append(f"only in {name}: " + ", ".join("/".join(k[:3]) for k in sorted(only)))
    errors = [k for k in both if facts(A[k])["error"] or facts(B[k])["error"]]
    if errors:
        out.append("errors: " + ", ".join("/".join(k[:3]) for k in errors))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="suite JSON, before (e.g. main's)")
    ap.add_argument("b", help="suite JSON, after")
    ap.add_argument("--changed", action="store_true",
                    help="only cases with a mark or a different first finding")
    ap.add_argument("--kind", help="only this change kind (thermal_mass, none, ...)")
    args = ap.parse_args(argv)
    A, B = load(args.a), load(args.b)
    print(f"A = {args.a}\nB = {args.b}")
    print("\n".join(table(A, B, args.changed, args.kind)))
    print()
    print("\n".join(summary(A, B)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

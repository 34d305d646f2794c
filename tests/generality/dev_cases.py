"""The fixed dev set of the diagnosis's start times and judge (docs/effects.md, "Start times and
the judge's power"): each case's first finding, start error, held-out cut and the suite's own p,
and the injected effect's own trial in the judge (cut, p, per-fold starts). Never the held-out
generator.

    python tests/generality/dev_cases.py --out after.jsonl [CASE ...]   # generator/window/kind
    python tests/generality/dev_cases.py --table before.jsonl after.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import START_TOLERANCE_H, diagnose_dev, own_significance  # noqa: E402
from tests.generality.generators import CHANGE_DAY, EXPECTED  # noqa: E402

KINDS = ("transmission", "ventilation", "thermal_mass", "sun_sensor", "drift")
DEV = [f"{g}/{w}/{k}" for g in ("refsim", "twonode") for w in ("autumn", "winter") for k in KINDS]


def run_case(label: str) -> dict:
    import numpy as np

    t0 = time.process_time()
    data, _, d = diagnose_dev(label)
    f = d.findings[0] if d.findings else None
    err = None
    if f is not None and data.start is not None and f.start is not None:
        lag = np.datetime64(str(f.start).rstrip("Z"), "s") - data.start
        err = float(lag / np.timedelta64(1, "h"))
    b, a = d.before["free_run"]["mae"], d.after["free_run"]["mae"]
    keys = ("round", "effect", "ok", "p", "cut", "cut_reference", "halves", "starts", "late")
    return {"case": label, "first": f.effect.name if f else None, "start_err_h": err,
            "cut": 1.0 - a / b, "p_suite": own_significance(d),
            "trials": [{key: t[key] for key in keys} for t in d.trials],
            "cpu_s": time.process_time() - t0}


def _cell(r: dict | None) -> str:
    if r is None:
        return "–"
    if r["first"] is None:
        return "none"
    kind = r["case"].split("/")[2]
    err = r["start_err_h"]
    ok = (r["first"] in EXPECTED.get(kind, ()) and err is not None
          and abs(err) <= START_TOLERANCE_H and r["cut"] >= 0.2 and (r["p_suite"] or 1.0) < 0.05)
    e = f"{err:+.1f} h" if err is not None else "–"
    return f"`{r['first']}` {e}, {-100 * r['cut']:.0f} %, p {r['p_suite']:.3f}{' ✓' if ok else ''}"


def _own_trial(r: dict | None) -> str:
    if r is None:
        return "–"
    kind = r["case"].split("/")[2]
    t = [t for t in r["trials"] if t["effect"] in EXPECTED.get(kind, ()) and t["round"] == 1]
    if not t:
        return "not tried"
    starts = "/".join(f"{s / 86400 - CHANGE_DAY:+.1f}" for s in t[0]["starts"])
    return f"cut {-100 * t[0]['cut']:.0f} %, p {t[0]['p']:.3f}, starts {starts} d"


def table(before: Path, after: Path) -> str:
    def load(p: Path) -> dict:
        return {r["case"]: r for r in map(json.loads, p.read_text(encoding="utf-8").splitlines())}

    b, a = load(before), load(after)
    rows = ["| case | before: first finding, start error, held-out cut, suite p | after | right "
            "effect's judge before → after (cut, p, fold starts − truth) |", "| --- | --- | --- | --- |"]
    for k in b:
        rows.append(f"| {k} | {_cell(b[k])} | {_cell(a.get(k))} | {_own_trial(b[k])} → "
                    f"{_own_trial(a.get(k))} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", help="generator/window/kind (default: the dev set)")
    ap.add_argument("--out", help="JSON lines to append to")
    ap.add_argument("--table", nargs=2, metavar=("BEFORE", "AFTER"), help="print the table only")
    a = ap.parse_args(argv)
    if a.table:
        print(table(Path(a.table[0]), Path(a.table[1])))
        return 0
    if not a.out:
        ap.error("--out is required to run cases")
    with open(a.out, "a", encoding="utf-8") as out:
        for label in a.cases or DEV:
            rec = run_case(label)
            out.write(json.dumps(rec) + "\n")
            out.flush()
            print(f"{label}: {_cell(rec)} | {_own_trial(rec)} ({rec['cpu_s']:.0f} s CPU)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

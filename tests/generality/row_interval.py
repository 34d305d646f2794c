"""The diagnosis of a dev case at several logger row intervals, one JSON line each (docs/effects.md,
"Logger row intervals"). The generators read the kit's sensors every 60 s; a logger logging
every ``row_s`` keeps every k-th reading (instantaneous samples, the suite's own way at 300 s:
the same noise and 0.1 quantisation). The kit CSV is written and read back at ``row_s`` as a
user's would be (``--mean``: block means of the 1-minute readings instead). Never the
held-out generator.

    PYTHONPATH=<tree> python tests/generality/row_interval.py refsim/autumn/heater ... \\
        [--rows 60,300,600,900] [--mean] > out.jsonl
    python tests/generality/row_interval.py --table out.jsonl   # the rule, against 300 s

The rule (written before measuring): against the 300-s run of the same case, every other
interval gives the same first finding (or none), its start within START_TOLERANCE_H, and a
held-out free-run MAE after within MAE_TOLERANCE (relative); no crash at any interval.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from tests.generality.cases import START_TOLERANCE_H, dev_label, window  # noqa: E402
from tests.generality.generators import generate  # noqa: E402

ROWS_S = (60.0, 300.0, 600.0, 900.0)
REFERENCE_S = 300.0
MAE_TOLERANCE = 0.10
"""Relative difference of the held-out free-run MAE after to the 300-s run's."""


def diagnose_at(label: str, row_s: float, mean: bool = False) -> dict:
    """``label`` = generator/window/kind (seed 1) logged every ``row_s`` and diagnosed;
    ``mean``: rows are block means of the 1-minute readings over ``row_s`` (a logger averaging
    over its interval: the 60-s CSV read back at ``row_s``, ``load_series`` averages)."""
    from gateway.diagnose import diagnose
    from gateway.model import build_model
    from gateway.series import load_series

    g, w, k = dev_label(label)
    out: dict = {"case": label, "row_s": row_s, "rows": "mean" if mean else "point"}
    t0 = time.perf_counter()
    try:
        data = generate(g, window(w), k, 1, row_s=60.0 if mean else row_s)
        gh = data.greenhouse()
        model = build_model("prototype", gh)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "kit.csv"
            data.write_csv(path)
            series = load_series(str(path), step=row_s, required=model.requires)
        d = diagnose(series, gh, model)
        first = d.findings[0] if d.findings else None
        out.update(findings=[f.effect.name for f in d.findings],
                   start=str(first.start) if first is not None and first.start is not None else None,
                   truth=None if data.start is None else str(data.start),
                   mae_before=d.before["free_run"]["mae"], mae_after=d.after["free_run"]["mae"],
                   unexplained=d.unexplained)
    except Exception as exc:  # a failing interval is a row of the table
        out["error"] = f"{type(exc).__name__}: {exc}"
    out["s"] = round(time.perf_counter() - t0, 1)
    return out


def _hours(a: str, b: str) -> float:
    return float((np.datetime64(a.rstrip("Z"), "s") - np.datetime64(b.rstrip("Z"), "s"))
                 / np.timedelta64(1, "h"))


def judge(row: dict, ref: dict) -> dict:
    """The rule for one interval's ``row`` against the 300-s run ``ref`` of the same case."""
    if "error" in row or "error" in ref:
        return {"ok": False, "why": row.get("error") or "reference failed"}
    first = row["findings"][:1]
    same = first == ref["findings"][:1]
    both = row["start"] is not None and ref["start"] is not None
    start_ok = not first or row["start"] == ref["start"] or (
        both and abs(_hours(row["start"], ref["start"])) <= START_TOLERANCE_H)
    mae_ok = abs(row["mae_after"] / ref["mae_after"] - 1.0) <= MAE_TOLERANCE
    return {"ok": bool(same and start_ok and mae_ok), "same_first": same, "start_ok": start_ok,
            "mae_ratio": round(row["mae_after"] / ref["mae_after"], 3)}


def table(path: str) -> None:
    rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    ref = {r["case"]: r for r in rows if r["row_s"] == REFERENCE_S}
    for r in rows:
        v = judge(r, ref[r["case"]]) if r["case"] in ref else {"ok": None}
        first = (r.get("findings") or ["—"])[0] if "error" not in r else "error"
        lag = _hours(r["start"], r["truth"]) if r.get("start") and r.get("truth") else None
        print(f"{r['case']:28s} {r['row_s']:5.0f} s  {first:22s} "
              f"start-truth {'—' if lag is None else f'{lag:+.1f} h':>8s}  "
              f"MAE after {r.get('mae_after', float('nan')):.3f} K  {json.dumps(v)}")


if __name__ == "__main__":
    args = sys.argv[1:]
    if args and args[0] == "--table":
        table(args[1])
        raise SystemExit(0)
    rows_s = ROWS_S
    mean = "--mean" in args
    if mean:
        args.remove("--mean")
    if "--rows" in args:
        i = args.index("--rows")
        rows_s = tuple(float(x) for x in args[i + 1].split(","))
        del args[i:i + 2]
    for case in args:
        for row_s in rows_s:
            print(json.dumps(diagnose_at(case, row_s, mean)), flush=True)

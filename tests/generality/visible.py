"""How much each injected change moved the kit's reading, and the verdicts rescored with it.

A change the data does not show (a controller whose vents never reach their cap in winter)
cannot be diagnosed by any method; the suite judges such a case as effect-free data
(``cases.MIN_VISIBLE_K``). Runs written before the suite measured this lack ``visible_k``:
this adds it (regenerating each case's data with and without its change, no diagnosis) and
rescores the verdicts with ``cases.verdict``.

    python tests/generality/visible.py RESULTS.json... [--write]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import MIN_VISIBLE_K, Case, case_visible_change, verdict, window  # noqa: E402
from tests.generality.generators import generate  # noqa: E402


def add_visible(results: list[dict]) -> list[tuple[str, float, bool, bool]]:
    """Set ``visible_k`` and the verdict of every diagnosed change in ``results`` (in place);
    (label, visible_k, ok before, ok after) per case."""
    rows = []
    for r in results:
        case = Case(**r["case"])
        if case.task != "diagnose" or case.kind == "none" or "error" in r:
            continue
        data = generate(case.generator, window(case.window), case.kind, case.seed)
        was = bool(r["verdict"]["ok"])
        r["visible_k"] = case_visible_change(case, data)
        r["verdict"] = verdict(case.kind, r)
        rows.append((case.label, r["visible_k"], was, bool(r["verdict"]["ok"])))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="suite results files (JSON)")
    ap.add_argument("--write", action="store_true", help="write visible_k and the verdicts back")
    a = ap.parse_args(argv)
    for path in a.results:
        data = json.loads(path.read_text(encoding="utf-8"))
        rows = add_visible(data["results"])
        print(f"{path}: mean |change of the t_in reading| after the start [K] "
              f"(judged as effect-free below {MIN_VISIBLE_K:g})")
        for label, k, was, now in sorted(rows):
            mark = "  no visible change" if k < MIN_VISIBLE_K else ""
            moved = f"  ok {was} -> {now}" if was != now else ""
            print(f"  {label:48s} {k:6.3f}{mark}{moved}")
        if a.write:
            path.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
            print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

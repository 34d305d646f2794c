"""Rule ho (docs/effects.md, "The base calibrated on half-day free runs"): the diagnosis's base
held-out free-run MAE on the tuning generators' 20 effect-free windows, with the base
calibrated on the search's 6-h shooting windows (``off``) or on 12-h ones (``on``,
base.BASE_HORIZON_S). One JSON line per window; compare two runs with
``tests/generality/horizon_study.py --compare off.jsonl on.jsonl``.

    .venv/bin/python tests/generality/horizon_study.py off --out out/ho/off.jsonl   # ~10 min
    .venv/bin/python tests/generality/horizon_study.py on --out out/ho/on.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import Case, case_series  # noqa: E402
from tests.generality.sky_study import WINDOWS  # noqa: E402


def run(on: bool, out: Path) -> None:
    """Diagnose every effect-free window of refsim and twonode; one line per window."""
    import gateway.diagnose.base as base
    from gateway.diagnose import diagnose

    base.BASE_HORIZON_S = 12 * 3600.0 if on else None
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w") as f:
        for g in ("refsim", "twonode"):
            for name in WINDOWS:
                with tempfile.TemporaryDirectory() as tmp:
                    _, gh, model, series = case_series(Case("diagnose", g, name, "none"), Path(tmp))
                    d = diagnose(series, gh, model)
                r = d.measured[d.split_index:] - d.pred_before["free_run"]
                row = {"generator": g, "window": name, "mae": float(np.nanmean(np.abs(r))),
                       "kept": [s["structure"] for s in d.structure
                                if s["kept"] and s["structure"] != "base"],
                       "findings": [x.effect.name for x in d.findings]}
                f.write(json.dumps(row) + "\n")
                f.flush()
                print(f"{g} {name}: {row['mae']:.3f} K", flush=True)


def compare(a_path: Path, b_path: Path) -> None:
    """Per-window table, generator and pooled means, windows worse by > 10 %."""
    a = {(r["generator"], r["window"]): r for r in map(json.loads, a_path.open())}
    b = {(r["generator"], r["window"]): r for r in map(json.loads, b_path.open())}
    print("| generator | window | 6-h windows [K] | 12-h windows [K] | change | parts kept (12 h) | "
          "findings 6 h / 12 h |\n|---|---|---|---|---|---|---|")
    pairs: dict[str, list[tuple[float, float]]] = {}
    for k in a:
        x, y = a[k]["mae"], b[k]["mae"]
        pairs.setdefault(k[0], []).append((x, y))
        print(f"| {k[0]} | {k[1]} | {x:.3f} | {y:.3f} | {100 * (y / x - 1):+.1f} % | "
              f"{', '.join(b[k]['kept']) or '-'} | {', '.join(a[k]['findings']) or 'none'} / "
              f"{', '.join(b[k]['findings']) or 'none'} |")
    every = [p for v in pairs.values() for p in v]
    for label, v in [*pairs.items(), ("pooled", every)]:
        mx, my = np.mean([p[0] for p in v]), np.mean([p[1] for p in v])
        print(f"{label}: {mx:.3f} -> {my:.3f} K ({100 * (my / mx - 1):+.1f} %)")
    print("windows worse by > 10 %:", sum(y > 1.1 * x for x, y in every))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("switch", nargs="?", choices=("off", "on"))
    ap.add_argument("--out", type=Path, help="JSON lines, one per window")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("OFF", "ON"))
    a = ap.parse_args(argv)
    if a.compare:
        compare(*a.compare)
        return 0
    if a.switch is None or a.out is None:
        ap.error("give off|on and --out (or --compare OFF ON)")
    run(a.switch == "on", a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

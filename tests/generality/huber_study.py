"""Rule hb (docs/effects.md, "The base fitted with a Huber loss"), step 1: the diagnosis's base
held-out free-run MAE on the tuning generators' 20 effect-free windows, with the base fitted by
least squares (``off``, main) or polished on the Huber loss (``on``, base.HUBER). Never the
held-out generator.

    .venv/bin/python tests/generality/huber_study.py off --out out/hb/off.json   # ~6 min, one core
    .venv/bin/python tests/generality/huber_study.py on --out out/hb/on.json     # ~7 min
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import Case, case_series  # noqa: E402
from tests.generality.sky_study import WINDOWS  # noqa: E402


def run(on: bool, out: Path) -> None:
    """Diagnose every effect-free window of refsim and twonode; one row per window."""
    import gateway.diagnose.base as base
    from gateway.diagnose import diagnose

    base.HUBER = on
    rows = []
    for g in ("refsim", "twonode"):
        for name in WINDOWS:
            c0 = time.process_time()
            with tempfile.TemporaryDirectory() as tmp:
                _, gh, model, series = case_series(Case("diagnose", g, name, "none"), Path(tmp))
                d = diagnose(series, gh, model)
            r = d.measured[d.split_index:] - d.pred_before["free_run"]
            rows.append({"generator": g, "window": name, "mae": float(np.nanmean(np.abs(r))),
                         "kept": [s["structure"] for s in d.structure
                                  if s["kept"] and s["structure"] != "base"],
                         "findings": [f.effect.name for f in d.findings],
                         "cpu": time.process_time() - c0})
            print(json.dumps(rows[-1]), flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("switch", choices=("off", "on"))
    ap.add_argument("--out", type=Path, required=True, help="JSON, one row per window")
    a = ap.parse_args(argv)
    run(a.switch == "on", a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

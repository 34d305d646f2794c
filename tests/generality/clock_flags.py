"""The unexplained flag of the generality suite's dev diagnosis cases, one JSON line each (docs/
effects.md, "The clock of the time-of-day features"): flag, findings, held-out free-run MAE
and signature, to compare two trees' clocks side by side. Never the held-out generator.

    PYTHONPATH=<tree> python tests/generality/clock_flags.py refsim/autumn/misting ... > out.jsonl
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import diagnose_dev  # noqa: E402


def flags(label: str) -> dict:
    """``label`` = generator/window/kind (the suite's seed 1) diagnosed as the suite does."""
    t0 = time.perf_counter()
    _, gh, d = diagnose_dev(label)
    return {"case": label, "lon": gh.site.longitude if gh.site else None,
            "unexplained": d.unexplained, "findings": [f.effect.name for f in d.findings],
            "mae_after": d.after["free_run"]["mae"], "signature": d.signature,
            "s": round(time.perf_counter() - t0)}


if __name__ == "__main__":
    for case in sys.argv[1:]:
        print(json.dumps(flags(case)), flush=True)

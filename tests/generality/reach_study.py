"""How much of each injected change reaches the kit's inside reading: the change's kit T_in
minus the effect-free kit T_in (same generator, window, weather and seed), after the change's
start, as mean |ΔT_in| [K] over all rows and over daytime rows (I_glob > 50 W m-2). A change
that moves the reading less than the base's held-out error cannot be named with a 20 % cut.

    .venv/bin/python tests/generality/reach_study.py [--generators refsim,twonode]
        [--windows autumn,winter,summer]    # ~1 min on one core
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.generators import HELD_OUT, KINDS, generate  # noqa: E402
from tests.generality.windows import load_window  # noqa: E402

DAY_W_M2 = 50.0  # [W m-2] a daytime row


def reach(generator: str, window: str, kind: str) -> tuple[float, float]:
    """(mean |ΔT_in| all rows, daytime rows) [K] after the change's start."""
    w = load_window(window)
    base, d = generate(generator, w, "none"), generate(generator, w, kind)
    after = d.time >= d.start
    dt = np.abs(d.columns["t_in"][after] - base.columns["t_in"][after])
    day = base.columns["i_glob"][after] > DAY_W_M2
    return float(np.nanmean(dt)), float(np.nanmean(dt[day]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generators", default="refsim,twonode",
                    help="never the held-out one (default: refsim,twonode)")
    ap.add_argument("--windows", default="autumn,winter,summer")
    a = ap.parse_args(argv)
    gens = a.generators.split(",")
    if set(gens) & set(HELD_OUT):
        ap.error(f"{', '.join(HELD_OUT)} is held out: not studied")
    print("| generator | window | " + " | ".join(KINDS) + " |")
    print("| --- " * (len(KINDS) + 2) + "|")
    for g in gens:
        for w in a.windows.split(","):
            cells = [reach(g, w, k) for k in KINDS]
            print(f"| {g} | {w} | " + " | ".join(f"{m:.2f} / {d:.2f}" for m, d in cells) + " |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

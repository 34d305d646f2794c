"""The weather outlooks side by side on the same replays: ``hold-latest`` against
``clear-sky-trend`` (gateway/estimate/outlook.py), which the live gateway could use.

Scores the replays pickled by ``tests/generality/forecasts.py --keep DIR`` again, once per
outlook: the estimator's loop is not run again, so both outlooks forecast from the very same
parameters in force at each start. Prints the 15/30/60-min MAE [K] of the outlook forecasts
(adaptive, adaptive + disturbance filter, combined, ARX) beside persistence, per case.

    nice -n 5 .venv/bin/python tests/generality/forecasts.py --generators refsim,twonode \\
        --windows winter --keep /tmp/keep --json /tmp/forecasts.json
    .venv/bin/python tests/generality/outlooks.py /tmp/keep [--json outlooks.json]
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

PARTS = ("adaptive", "adaptive_kf", "combined", "arx")


def score(res, outlook_name: str) -> dict[str, dict[str, float]]:
    """Horizon [min] → forecast → MAE of ``res`` (a ``ReplayResult``) with ``outlook_name``."""
    import numpy as np

    from gateway.estimate.horizon import outlook_drivers
    from gateway.estimate.outlook import make_outlook
    from gateway.estimate.replay import HORIZONS, report, score_forecasts, steps_of
    from gateway.kitcsv import COLUMNS

    reach = steps_of(HORIZONS, res.dt)
    kit = [c for c in COLUMNS if c in res.x]  # the kit columns the replay read
    n = len(res.time)
    res.ahead = outlook_drivers(make_outlook(outlook_name, res.gh), res.x, kit, res.time, res.dt,
                                res.gh, np.arange(max(n - 1, 0)), max(reach.values()))
    score_forecasts(res, reach)
    rep = report(res, warmup=int(round(86400.0 / res.dt)))
    return {h: {name: m["mae"] for name, m in per.items()} for h, per in rep["horizons"].items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="replays pickled by forecasts.py --keep")
    ap.add_argument("--json", help="also write the figures here")
    a = ap.parse_args(argv)
    from gateway.estimate.outlook import OUTLOOKS

    names = sorted(OUTLOOKS)
    rows, out = [], {}
    for f in sorted(Path(a.folder).glob("*.pkl")):
        res = pickle.loads(f.read_bytes())
        per = {name: score(res, name) for name in names}
        out[f.stem] = per
        for h in per[names[0]]:
            cells = [f"{per[names[0]][h]['persistence']:.3f}"]
            for part in PARTS:
                cells += [f"{per[o][h][f'{part}_outlook']:.3f}" for o in names]
            rows.append(f"| {f.stem} | {h} | " + " | ".join(cells) + " |")
    head = " | ".join(f"{p}, {o}" for p in PARTS for o in names)
    print(f"| case | h [min] | persistence | {head} |")
    print("|" + " --- |" * (3 + len(PARTS) * len(names)))
    print("\n".join(rows))
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The ft rule (docs/online-estimator.md, "The reading's trend in the correction"): the kept
replays of the tuning windows scored twice, the correction's "t_in trend" column held at 0 (the
fit before the feature: the ridge decouples a zero column) and with it; the rule's four
conditions and the table per window and horizon. The held-out generator's replays are skipped
unless ``--held-out`` (the lead's one scoring after the verdict, reported apart).

    nice -n 5 .venv/bin/python tests/generality/forecasts.py --generators refsim,twonode \\
        --jobs 1 --keep out/ft/fc
    .venv/bin/python tests/generality/trend_rule.py out/ft/fc
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.estimate import correction  # noqa: E402
from gateway.estimate import replay as rp  # noqa: E402
from tests.generality.correction_study import _corrected  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402
from tests.generality.report import goals  # noqa: E402

TREND = "t_in trend"


def scored(res, with_trend: bool) -> dict[str, dict]:
    """The replay's report horizons with ``corrected{,_outlook}`` rescored, the trend column
    kept or held at 0."""
    mask = np.array([1.0 if with_trend or n != TREND else 0.0 for n in correction.FEATURES])
    _corrected(res, mask, correction.MEMORY_S, correction.RIDGE)
    return rp.report(res, warmup=int(round(86400.0 / res.dt)))["horizons"]


def window_goals(hs: dict) -> tuple[bool, bool]:
    """(measured-weather goal at every horizon, outlook goal at 30 and 60 min) of ``corrected``."""
    g = [goals(h, "corrected", int(m)) for m, h in hs.items()]
    return all(m for m, _ in g), all(o is not False for _, o in g)


def verdict(rows: list[tuple[str, dict, dict]]) -> tuple[bool, list[str]]:
    """The rule's (a)–(d) on (window, main horizons, candidate horizons) rows, with the table."""
    mark = {True: "✓", False: "✗"}
    lines = ["| window | h [min] | persistence | corrected main → trend | change | corrected, "
             "outlook main → trend | change |", "| --- " * 7 + "|"]
    ratios: dict[str, list[float]] = {"": [], "_outlook": []}
    met = np.zeros((2, 2), dtype=int)  # [main, cand] × [measured, outlook]
    for w, m, c in rows:
        for i, hs in enumerate((m, c)):
            met[i] += window_goals(hs)
        for h in m:
            cells = []
            for suffix, r in ratios.items():
                a, b = m[h][f"corrected{suffix}"]["mae"], c[h][f"corrected{suffix}"]["mae"]
                r.append(b / a)
                cells += [f"{a:.3f} → {b:.3f}", f"{100 * (b / a - 1):+.1f} %"]
            lines.append(f"| {w} | {h} | {m[h]['persistence']['mae']:.3f} | " + " | ".join(cells) + " |")
    worst = max(max(r) for r in ratios.values())
    checks = {
        "(a) measured goal windows ≥ main + 1": (met[1, 0] >= met[0, 0] + 1, f"{met[0, 0]} → {met[1, 0]}"),
        "(b) outlook goal windows ≥ main": (met[1, 1] >= met[0, 1], f"{met[0, 1]} → {met[1, 1]}"),
        "(c) mean ratio ≤ 0.99 measured, ≤ 1.00 outlook": (
            np.mean(ratios[""]) <= 0.99 and np.mean(ratios["_outlook"]) <= 1.0,
            f"{np.mean(ratios['']):.4f}, {np.mean(ratios['_outlook']):.4f}"),
        "(d) no window-horizon worse by > 3 %": (worst <= 1.03, f"worst {100 * (worst - 1):+.1f} %"),
    }
    lines += ["", "| condition | value | met |", "| --- | --- | --- |"]
    lines += [f"| {k} | {v} | {mark[bool(ok)]} |" for k, (ok, v) in checks.items()]
    ok = all(bool(v[0]) for v in checks.values())
    lines.append(f"\nverdict: {'PASSES' if ok else 'FAILS'}")
    return ok, lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kept", help="the directory of tests/generality/forecasts.py --keep")
    ap.add_argument("--held-out", action="store_true",
                    help="score the held-out generator's replays instead (after the verdict)")
    a = ap.parse_args(argv)
    rows = []
    for f in sorted(Path(a.kept).glob("*.pkl")):
        if (f.stem.split("-", 1)[0] in HELD_OUT) != a.held_out:
            continue
        res = pickle.loads(f.read_bytes())
        rp.score_forecasts(res, rp.steps_of(rp.HORIZONS, res.dt))
        rows.append((f.stem, scored(res, False), scored(res, True)))
    if not rows:
        raise SystemExit(f"{a.kept}: no kept replays of the {'held-out' if a.held_out else 'tuning'} "
                         "generators")
    ok, lines = verdict(rows)
    print("\n".join(lines))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())

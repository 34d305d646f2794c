"""The ol rule (stated in docs/effects.md "The outlook's drivers, one at a time")
on two results files of tests/generality/forecasts.py (main, candidate) over the dev windows.

(a) the outlook goals met (``corrected_outlook`` ≤ 0.8 × persistence at 30 and 60 min) and the
measured-weather goals (``corrected`` ≤ 0.7 × persistence and below the ARX, at every horizon),
per window, none met by main lost; the mean over the outlook cells of ``corrected_outlook`` /
persistence and its change (≤ −3 % passes); (b) the worst cell change of ``corrected_outlook``
(≤ +2 %) and the largest change of ``corrected`` (≤ 0.5 %).

    .venv/bin/python tests/generality/outlook_rule.py out/ol/main.json out/ol/cand/X.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.generators import HELD_OUT  # noqa: E402
from tests.generality.report import goals  # noqa: E402


def _load(path: str) -> dict[str, dict]:
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    return {f"{r['case']['generator']} {r['case']['window']}": r["horizons"] for r in data["results"]
            if "error" not in r and r["case"]["generator"] not in HELD_OUT}


def _goals(hs: dict) -> tuple[bool, bool]:
    """(measured-weather goal, outlook goal) of ``corrected`` on one window."""
    g = [goals(h, "corrected", int(m)) for m, h in hs.items()]
    return all(m for m, _ in g), all(o is not False for _, o in g)


def verdict(main: dict[str, dict], cand: dict[str, dict]) -> tuple[bool, list[str]]:
    wins = [w for w in main if w in cand]
    lines = ["| window | measured goal main → cand | outlook goal main → cand |", "| --- | --- | --- |"]
    lost, gained, met = False, 0, [0, 0]
    mark = {True: "✓", False: "✗"}
    for w in wins:
        gm, gc = _goals(main[w]), _goals(cand[w])
        lost |= any(a and not b for a, b in zip(gm, gc, strict=True))
        gained += gc[1] - gm[1]
        met[0] += gm[1]
        met[1] += gc[1]
        lines.append(f"| {w} | {mark[gm[0]]} → {mark[gc[0]]} | {mark[gm[1]]} → {mark[gc[1]]} |")

    def mean(d: dict) -> float:
        r = [h["corrected_outlook"]["mae"] / h["persistence"]["mae"] for w in wins for h in d[w].values()]
        return sum(r) / len(r)

    m0, m1 = mean(main), mean(cand)
    change = 100.0 * (m1 / m0 - 1.0)
    worst = max(((cand[w][h]["corrected_outlook"]["mae"] / main[w][h]["corrected_outlook"]["mae"] - 1)
                 * 100.0, f"{w} {h}") for w in wins for h in main[w])
    moved = max(abs(cand[w][h]["corrected"]["mae"] / main[w][h]["corrected"]["mae"] - 1) * 100.0
                for w in wins for h in main[w])
    a = not lost and (gained > 0 or change <= -3.0)
    b = worst[0] <= 2.0 and moved <= 0.5
    lines += ["", f"outlook goals met: {met[0]} → {met[1]} of {len(wins)}; a goal met by main lost: {lost}",
              f"mean over {sum(len(main[w]) for w in wins)} cells of corrected_outlook / persistence: "
              f"{m0:.4f} → {m1:.4f} ({change:+.2f} %)",
              f"(a) {'met' if a else 'NOT met'}",
              f"(b) worst corrected_outlook cell {worst[0]:+.2f} % ({worst[1]} min); largest change of "
              f"corrected {moved:.2f} %: {'met' if b else 'NOT met'}",
              f"verdict (a and b; c is the command): {'PASSES' if a and b else 'fails'}"]
    return a and b, lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("main")
    ap.add_argument("candidate")
    a = ap.parse_args(argv)
    _, lines = verdict(_load(a.main), _load(a.candidate))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Two results files of tests/generality/forecasts.py side by side: MAE [K] before → after.

Per window and horizon, for the named forecasts: the MAE in each file, an arrow where the second
differs by more than 0.0005 K (⬇ better, ⬆ worse), persistence and the ARX (from the second
file), and whether ``corrected`` meets issue 10's measured-weather goal in each.

    .venv/bin/python tests/generality/compare_forecasts.py BEFORE.json AFTER.json
        [--forecasts adaptive,adaptive_kf,combined,corrected,corrected_outlook]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.report import goals  # noqa: E402

MARK = {True: "✓", False: "✗"}


def _by_window(path: str) -> dict[tuple[str, str], dict]:
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    return {(r["case"]["generator"], r["case"]["window"]): r for r in data["results"] if "error" not in r}


def table(before: str, after: str, names: list[str]) -> str:
    a, b = _by_window(before), _by_window(after)
    lines = ["| window | h [min] | persistence | ARX | " + " | ".join(names)
             + " | corrected: goal (measured) |", "| --- " * (len(names) + 5) + "|"]
    for key in (k for k in b if k in a):
        for minutes, hb in b[key]["horizons"].items():
            ha = a[key]["horizons"][minutes]
            cells = []
            for n in names:
                x, y = ha[n]["mae"], hb[n]["mae"]
                arrow = " ⬇" if y < x - 5e-4 else (" ⬆" if y > x + 5e-4 else "")
                cells.append(f"{x:.3f} → {y:.3f}{arrow}")
            g = [MARK[goals(h, "corrected", int(minutes))[0]] for h in (ha, hb)]
            lines.append(f"| {' '.join(key)} | {minutes} | {hb['persistence']['mae']:.3f} | "
                         f"{hb['arx']['mae']:.3f} | " + " | ".join(cells) + f" | {g[0]} → {g[1]} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--forecasts", default="adaptive,adaptive_kf,combined,corrected,corrected_outlook")
    a = ap.parse_args(argv)
    print(table(a.before, a.after, [n for n in a.forecasts.split(",") if n]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

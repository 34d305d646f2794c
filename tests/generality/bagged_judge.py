"""Rule bq (issue 10, step 2a; docs/effects.md, "A bagged base"): the dev suite's diagnosis
results with the bagged judge (``suite.py --bags 5``) against main's (``--bags 0``), read from
the suite's results files, and the rule's verdict on the windows both runs hold.

    PYTHONPATH=. python tests/generality/bagged_judge.py --main out/bq_bags0_*.json \
        --bagged out/bq_bags5_*.json [--out out/bq_verdict]

(a) each dev generator quiet in >= 9 of its 10 effect-free windows (bagged); (b) effect kinds
passing summed over the dev effect windows: bagged >= main + 2; (c) no window's kinds count
falls by more than 1; (d) visible changes outside the library reported unexplained: bagged
total >= main total - 1. A window or effect-free set missing from either run is reported
missing, and the verdict then says partial: it fails on a failed (a) or (c), which the missing
windows cannot undo, and is otherwise undecided.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.generators import HELD_OUT, OUTSIDE  # noqa: E402
from tests.generality.report import MAIN_WINDOWS, _kinds_passed  # noqa: E402

DEV = ("refsim", "twonode")
EFFECT_FREE = 10
"""Effect-free windows per generator in the suite (3 main + 7 extra)."""


def load(files: list[str]) -> dict[tuple, dict]:
    """The suite's results of ``files`` by (generator, window, kind); never a held-out one."""
    out = {}
    for f in files:
        for r in json.loads(Path(f).read_text(encoding="utf-8"))["results"]:
            c = r["case"]
            if c["generator"] in HELD_OUT:
                raise SystemExit(f"{f}: {c['generator']} is held out")
            out[(c["generator"], c["window"], c["kind"])] = r
    return out


def window_figures(runs: dict[tuple, dict], g: str, w: str) -> dict | None:
    """Kinds passed / judged and visible outside changes reported unexplained on one effect
    window (report.py's counts); None when the run does not hold the window's 9 changes."""
    rows = [r for (gg, ww, k), r in runs.items() if gg == g and ww == w and k != "none"]
    if len(rows) < 9:
        return None
    passed, judged = _kinds_passed(rows, w)
    outside = [r for r in rows if r["case"]["kind"] in OUTSIDE
               and not r.get("verdict", {}).get("invisible")]
    return {"passed": len(passed), "judged": len(judged), "kinds": passed,
            "unexplained": sum(1 for r in outside if r["verdict"].get("ok")),
            "outside_visible": len(outside)}


def free_figures(runs: dict[tuple, dict], g: str) -> dict | None:
    """Quiet effect-free windows and their base held-out MAE; None unless all 10 are there."""
    rows = {w: r for (gg, w, k), r in runs.items() if gg == g and k == "none"}
    if len(rows) < EFFECT_FREE:
        return None
    quiet = sum(1 for r in rows.values() if r.get("verdict", {}).get("ok"))
    return {"quiet": quiet, "mae": {w: r.get("before") for w, r in rows.items()},
            "findings": {w: [f["effect"] for f in r.get("findings", [])] for w, r in rows.items()}}


def verdict(main: dict[tuple, dict], bagged: dict[tuple, dict]) -> dict:
    """The rule's four criteria on what both runs hold (``partial`` when not all of it)."""
    wins, missing = {}, []
    for w in MAIN_WINDOWS:
        for g in DEV:
            m, b = window_figures(main, g, w), window_figures(bagged, g, w)
            if m is None or b is None:
                missing.append(f"{g}/{w}")
            else:
                wins[f"{g}/{w}"] = {"main": m, "bagged": b}
    free = {}
    for g in DEV:
        m, b = free_figures(main, g), free_figures(bagged, g)
        if m is None or b is None:
            missing.append(f"{g}/effect-free")
        else:
            free[g] = {"main": m, "bagged": b}
    sum_m = sum(v["main"]["passed"] for v in wins.values())
    sum_b = sum(v["bagged"]["passed"] for v in wins.values())
    unexp_m = sum(v["main"]["unexplained"] for v in wins.values())
    unexp_b = sum(v["bagged"]["unexplained"] for v in wins.values())
    out = {"windows": wins, "free": free, "missing": missing, "partial": bool(missing),
           "kinds_main": sum_m, "kinds_bagged": sum_b, "unexplained_main": unexp_m,
           "unexplained_bagged": unexp_b,
           "a": all(v["bagged"]["quiet"] >= 9 for v in free.values()) if free else None,
           "b": (sum_b >= sum_m + 2) if wins else None,
           "c": all(v["bagged"]["passed"] >= v["main"]["passed"] - 1 for v in wins.values())
           if wins else None,
           "d": (unexp_b >= unexp_m - 1) if wins else None}
    # partial: (a) and (c) are final where measured (a window's fall, a generator's alarms);
    # (b) and (d) are sums the missing windows could still move
    final = [out["a"], out["c"]] if missing else [out[k] for k in "abcd"]
    out["passes"] = (all(out[k] for k in "abcd") if not missing else
                     (False if any(x is False for x in final) else None))
    return out


def seconds(main: dict[tuple, dict], bagged: dict[tuple, dict]) -> dict:
    """Diagnosis seconds per case both runs hold, and the mean ratio bagged / main."""
    both = sorted(set(main) & set(bagged))
    per = {"/".join(k): (main[k].get("diagnosis_seconds"), bagged[k].get("diagnosis_seconds"))
           for k in both}
    ratios = [b / m for m, b in per.values() if m and b]
    return {"cases": per, "mean_ratio": float(np.mean(ratios)) if ratios else None,
            "sum_main": float(sum(m for m, _ in per.values() if m)),
            "sum_bagged": float(sum(b for _, b in per.values() if b))}


def _case(r: dict | None) -> str:
    if r is None:
        return "–"
    if "error" in r:
        return "error"
    first = r["findings"][0]["effect"] if r["findings"] else "none"
    err = r.get("start_error_h")
    cut = r.get("cut")
    p = r.get("p_value")
    parts = [first]
    if r["findings"]:
        parts += [f"{err:+.1f} h" if err is not None else "start –",
                  f"cut {100 * cut:.0f} %" if cut is not None else "cut –",
                  f"p {p:.3f}" if p is not None else "p –"]
    if r.get("unexplained"):
        parts.append("unexplained")
    return ", ".join(parts) + (" ✓" if r.get("verdict", {}).get("ok") else " ✗")


def _outcome(passes: bool | None) -> str:
    return "undecided" if passes is None else ("passes" if passes else "fails")


def markdown(main: dict, bagged: dict, v: dict, sec: dict) -> str:
    def yes(x: bool | None) -> str:
        return "not measured" if x is None else ("pass" if x else "FAIL")

    lines = ["| window | kinds main | kinds bagged | unexplained main | unexplained bagged |",
             "|---|---|---|---|---|"]
    for name, f in v["windows"].items():
        m, b = f["main"], f["bagged"]
        lines.append(f"| {name} | {m['passed']}/{m['judged']} | {b['passed']}/{b['judged']} | "
                     f"{m['unexplained']}/{m['outside_visible']} | "
                     f"{b['unexplained']}/{b['outside_visible']} |")
    lines += ["", "| generator | quiet main | quiet bagged | base MAE main [K] | base MAE bagged [K] |",
              "|---|---|---|---|---|"]
    for g, f in v["free"].items():
        mm = np.mean([x for x in f["main"]["mae"].values() if x is not None])
        mb = np.mean([x for x in f["bagged"]["mae"].values() if x is not None])
        lines.append(f"| {g} | {f['main']['quiet']}/10 | {f['bagged']['quiet']}/10 | {mm:.3f} | "
                     f"{mb:.3f} ({100 * (mb / mm - 1):+.1f} %) |")
    lines += ["", "| case | main: first, start error, cut, p | bagged | seconds main / bagged |",
              "|---|---|---|---|"]
    for k in sorted(set(main) & set(bagged)):
        sm, sb = sec["cases"]["/".join(k)]
        extra = ""
        if k[2] == "none":
            extra = f"; base MAE {main[k].get('before'):.3f} → {bagged[k].get('before'):.3f}"
        lines.append(f"| {'/'.join(k)} | {_case(main[k])} | {_case(bagged[k])}{extra} | "
                     f"{sm:.0f} / {sb:.0f} |")
    lines += ["", f"Kinds passing over the windows both hold: main {v['kinds_main']}, bagged "
              f"{v['kinds_bagged']}; unexplained: main {v['unexplained_main']}, bagged "
              f"{v['unexplained_bagged']}. Diagnosis seconds: main {sec['sum_main']:.0f}, bagged "
              f"{sec['sum_bagged']:.0f}, mean ratio per case {sec['mean_ratio']:.2f}.",
              f"(a) {yes(v['a'])}; (b) {yes(v['b'])}; (c) {yes(v['c'])}; (d) {yes(v['d'])}."
              + (f" PARTIAL: missing {', '.join(v['missing'])}." if v["partial"] else "")
              + f" Step 2a: {_outcome(v['passes'])}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--main", nargs="+", required=True, help="the --bags 0 results files")
    ap.add_argument("--bagged", nargs="+", required=True, help="the --bags 5 results files")
    ap.add_argument("--out", default="out/bq_verdict")
    a = ap.parse_args(argv)
    m, b = load(a.main), load(a.bagged)
    v, sec = verdict(m, b), seconds(m, b)
    text = markdown(m, b, v, sec)
    Path(a.out + ".json").write_text(json.dumps({"verdict": v, "seconds": sec}, indent=1))
    Path(a.out + ".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

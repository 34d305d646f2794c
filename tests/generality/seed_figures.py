"""Suite figures per seed, the seed noise of one arm, and two arms compared over seeds.

    python tests/generality/seed_figures.py --pair main-s2.json k-s2.json --pair A-s3 B-s3 ...

Per run (suite.py ``--json``, diagnose rows): effect kinds passing per generator and main
window (the suite's count, report.py: x of 6, or of 5 where a kind has no visible change),
effect-free windows quiet per generator (x of 10), the passing cases. The seed noise of each
arm (its runs over seeds, a figure, not a decision): per window the range of the kinds count,
and the cases whose pass/fail is not the same on every seed. Over the pairs (A, B on one
seed): the kinds passing summed over the windows and seeds, B − A; the fewest quiet windows of
B in one generator-seed; the quiet total, B − A (the terms of the rule stated in docs/effects.md,
"The suite's seed noise", issue 10).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.report import MAIN_WINDOWS, _kinds_passed  # noqa: E402

CaseKey = tuple[str, str, str]
"""(generator, window, kind) of a diagnose case, the seed left out."""


def diagnose_rows(path: str | Path) -> tuple[int, list[dict]]:
    """(seed, the diagnose rows) of a suite results file; every row must carry the one seed."""
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    rows = [r for r in data["results"] if r["case"]["task"] == "diagnose"]
    seeds = {int(r["case"].get("seed", 1)) for r in rows}
    if len(seeds) != 1:
        raise ValueError(f"{path}: seeds {sorted(seeds)} in one run")
    return seeds.pop(), rows


def figures(rows: list[dict]) -> dict:
    """``kinds[(gen, window)] = (passed, judged)``, ``quiet[gen] = (quiet, windows)``,
    ``passes``, ``cases`` and ``ok[(gen, window, kind)]`` of one run's diagnose rows."""
    by_gen: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        by_gen[r["case"]["generator"]].append(r)
    kinds, quiet = {}, {}
    for g, rs in by_gen.items():
        for w in MAIN_WINDOWS:
            passed, judged = _kinds_passed(rs, w)
            kinds[(g, w)] = (len(passed), len(judged))
        free = [r for r in rs if r["case"]["kind"] == "none"]
        alarms = sum(1 for r in free if r.get("verdict", {}).get("false_alarm", True))
        quiet[g] = (len(free) - alarms, len(free))
    ok = {(r["case"]["generator"], r["case"]["window"], r["case"]["kind"]):
          bool(r.get("verdict", {}).get("ok")) for r in rows}
    return {"kinds": kinds, "quiet": quiet, "passes": sum(ok.values()), "cases": len(ok), "ok": ok}


def noise(runs: list[dict]) -> dict:
    """The seed noise of one arm's :func:`figures` over seeds: ``range[(gen, window)]`` of the
    kinds passing (max − min) and ``flips``, the cases (in every run) whose pass/fail differs."""
    keys = sorted(set.intersection(*(set(f["kinds"]) for f in runs)))
    spread = {k: max(f["kinds"][k][0] for f in runs) - min(f["kinds"][k][0] for f in runs)
              for k in keys}
    cases = sorted(set.intersection(*(set(f["ok"]) for f in runs)))
    flips = [c for c in cases if len({f["ok"][c] for f in runs}) > 1]
    return {"range": spread, "flips": flips, "cases": len(cases)}


def over_pairs(pairs: list[tuple[dict, dict]]) -> dict:
    """Arms A and B compared over complete seed pairs: ``kinds_a``/``kinds_b`` (kinds passing
    summed over the windows and seeds), ``fewest_quiet_b`` (B's fewest quiet effect-free windows
    in one generator-seed), ``quiet_a``/``quiet_b`` (quiet totals), ``passes_a``/``passes_b``."""
    def total(f: dict, part: str) -> int:
        return sum(v[0] for v in f[part].values())

    return {"kinds_a": sum(total(a, "kinds") for a, _ in pairs),
            "kinds_b": sum(total(b, "kinds") for _, b in pairs),
            "fewest_quiet_b": min(v[0] for _, b in pairs for v in b["quiet"].values()),
            "quiet_a": sum(total(a, "quiet") for a, _ in pairs),
            "quiet_b": sum(total(b, "quiet") for _, b in pairs),
            "passes_a": sum(a["passes"] for a, _ in pairs),
            "passes_b": sum(b["passes"] for _, b in pairs)}


def run_line(name: str, seed: int, f: dict) -> str:
    """One Markdown table row: kinds per generator/window, quiet per generator, passes."""
    kinds = " | ".join(f"{p}/{j}" for _, (p, j) in sorted(f["kinds"].items(), key=_window_order))
    quiet = " | ".join(f"{q}/{n}" for _, (q, n) in sorted(f["quiet"].items()))
    total = sum(p for p, _ in f["kinds"].values())
    return f"| {name} | {seed} | {kinds} | {total} | {quiet} | {f['passes']}/{f['cases']} |"


def _window_order(item) -> tuple[str, int]:
    (g, w), _ = item
    return g, MAIN_WINDOWS.index(w)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pair", nargs=2, action="append", required=True, metavar=("A.json", "B.json"),
                    help="A and B run on one seed (repeat per seed)")
    ap.add_argument("--verdicts", action="store_true",
                    help="also every case's pass/fail: the cases that differ between runs")
    a = ap.parse_args(argv)
    pairs, arms = [], {"A": [], "B": []}
    for fa, fb in a.pair:
        (sa, ra), (sb, rb) = diagnose_rows(fa), diagnose_rows(fb)
        if sa != sb:
            ap.error(f"{fa} is seed {sa}, {fb} seed {sb}")
        fA, fB = figures(ra), figures(rb)
        pairs.append((fA, fB))
        arms["A"].append((sa, Path(fa).name, fA))
        arms["B"].append((sb, Path(fb).name, fB))
    gw = sorted(pairs[0][0]["kinds"].items(), key=_window_order)
    print("| run | seed | " + " | ".join(f"{g} {w} kinds" for (g, w), _ in gw)
          + " | kinds sum | " + " | ".join(f"{g} quiet" for g in sorted(pairs[0][0]["quiet"]))
          + " | cases passing |")
    print("| --- " * (4 + len(gw) + len(pairs[0][0]["quiet"])) + "|")
    for arm in ("A", "B"):
        for seed, name, f in arms[arm]:
            print(run_line(f"{arm} {name}", seed, f))
    for arm in ("A", "B"):
        runs = [f for _, _, f in arms[arm]]
        if len(runs) < 2:
            continue
        n = noise(runs)
        spread = ", ".join(f"{g}/{w} {v}" for (g, w), v in sorted(n["range"].items(),
                                                                     key=_window_order))
        print(f"\nseed noise of {arm} (seeds {[s for s, _, _ in arms[arm]]}): kinds range per window: "
              f"{spread}; cases whose pass/fail differs between seeds: {len(n['flips'])} of "
              f"{n['cases']}: " + ", ".join("/".join(c) for c in n["flips"]))
    o = over_pairs(pairs)
    print(f"\nover {len(pairs)} pairs: kinds passing {o['kinds_a']} → {o['kinds_b']} "
          f"({o['kinds_b'] - o['kinds_a']:+d}); B's fewest quiet in one generator-seed "
          f"{o['fewest_quiet_b']} of 10; quiet total {o['quiet_a']} → {o['quiet_b']} "
          f"({o['quiet_b'] - o['quiet_a']:+d}); cases passing {o['passes_a']} → {o['passes_b']}")
    if a.verdicts:
        print("\n" + "\n".join(verdict_lines([(n, f) for arm in ("A", "B") for _, n, f in arms[arm]])))
    return 0


def verdict_lines(runs: list[tuple[str, dict]]) -> list[str]:
    """Every case's verdict in every run: a Markdown row (y/n per run) for each case whose
    verdict is not the same in all, then the count of the cases that pass or fail in all."""
    cases = sorted(set.intersection(*(set(f["ok"]) for _, f in runs)))
    lines = ["| case | " + " | ".join(n for n, _ in runs) + " |", "| --- " * (len(runs) + 1) + "|"]
    same = {True: 0, False: 0}
    for c in cases:
        seen = [f["ok"][c] for _, f in runs]
        if len(set(seen)) == 1:
            same[seen[0]] += 1
        else:
            lines.append(f"| {'/'.join(c)} | " + " | ".join("y" if v else "n" for v in seen) + " |")
    lines.append(f"\nthe other {same[True] + same[False]} cases: {same[True]} pass and "
                 f"{same[False]} fail in every run")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())

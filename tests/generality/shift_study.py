"""Step 1 of the cw rule (issue 10; /work/notes/cw-rule.txt; docs/effects.md, "Weighting the
base toward the held-out weather"): the base's held-out free-run MAE on the dev generators'
effect-free windows (refsim, twonode x the suite's 10 windows, seed 1), main's calibration and
``base.SHIFT_WEIGHTS`` on, side by side in one process on the same code.

The base is calibrated as the diagnosis calibrates it (search.prepare); its held-out MAE is the
diagnosis's "base" figure (search._report's ``before``: the free run on the data's own grid over
the held-out folds, |measured − model| averaged over the held-out rows; sky_study.py's "base MAE,
kit sky"), which does not depend on the effect search, so the search is not run. Never the
held-out generator.

    PYTHONPATH=. nice -n 5 python tests/generality/shift_study.py [--out out/cw]
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

from tests.generality.cases import EXTRA_WINDOWS, Case, case_series  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402
from tests.generality.report import MAIN_WINDOWS  # noqa: E402

DEV = ("refsim", "twonode")


def base_mae(series, gh, model) -> dict:
    """The base's held-out free-run MAE [K] on the data's grid, as ``diagnose`` reports it,
    the structure kept and the calibration's seconds."""
    from gateway.diagnose import judge as jd
    from gateway.diagnose.fit import drivers
    from gateway.diagnose.search import prepare

    t0 = time.process_time()
    start = prepare(series, gh, model)
    cpu = time.process_time() - t0
    st, k = start.state, start.k
    held = st.held
    xf = drivers(series, gh)
    nf, sf = len(series), st.ctx.split * k
    ffolds = [[(a * k, b * k if b < held.n else nf) for a, b in f] for f in held.folds]
    pred = jd.heldout(st.model0, [start.theta, start.theta], xf, gh, series.step, ffolds, sf,
                      nf)["free_run"]
    r = xf["t_in"][sf:] - pred
    kept = [s["structure"] for s in start.structure if s["kept"] and s["structure"] != "base"]
    return {"mae": float(np.nanmean(np.abs(r))), "kept": kept, "cpu_s": cpu,
            "theta": dict(zip(st.model0.names, map(float, start.theta), strict=True))}


def window_weights(series, gh) -> dict:
    """The weights the switch gives the final refit's windows (min, max) and the ratio's
    coefficients, for the table."""
    from gateway.diagnose import base as bs
    from gateway.diagnose.fit import HORIZON_S, coarsen, drivers, window_starts
    from gateway.diagnose.search import FIT_STEP_S
    from gateway.diagnose.shift_weights import fit_ratio, shift_weights

    coarse = coarsen(series, max(int(FIT_STEP_S // series.step), 1))
    x = drivers(coarse, gh)
    n, dt = len(coarse), coarse.step
    s, horizon = int(round(0.5 * n)), max(int(round(HORIZON_S / dt)), 2)
    ratio = fit_ratio(x, s, horizon)
    w = shift_weights(ratio, x, window_starts([(0, s)], horizon, skip=horizon), horizon)
    assert bs.SHIFT_WEIGHTS  # only called with the switch on
    return {"w_min": float(w.min()), "w_max": float(w.max()), "beta": ratio.beta.tolist()}


def run_window(generator: str, window: str, seed: int) -> dict:
    from gateway.diagnose import base as bs

    if generator in HELD_OUT:
        raise SystemExit(f"{generator} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = case_series(Case("diagnose", generator, window, "none", seed),
                                           Path(tmp))
    rec: dict = {"generator": generator, "window": window}
    for label, on in (("main", False), ("cand", True)):
        bs.SHIFT_WEIGHTS = on
        try:
            rec[label] = base_mae(series, gh, model)
            if on:
                rec["weights"] = window_weights(series, gh)
        finally:
            bs.SHIFT_WEIGHTS = False
    rec["change_pct"] = 100.0 * (rec["cand"]["mae"] / rec["main"]["mae"] - 1.0)
    return rec


def verdict(records: list[dict]) -> dict:
    """The rule's (a) pooled mean falls >= 5 %, (b) neither generator's mean rises, (c) at most
    3 of the windows worse by > 10 %."""
    main = np.array([r["main"]["mae"] for r in records])
    cand = np.array([r["cand"]["mae"] for r in records])
    pooled = 100.0 * (cand.mean() / main.mean() - 1.0)
    gens = {}
    for g in sorted({r["generator"] for r in records}):
        m = np.array([r["generator"] == g for r in records])
        gens[g] = {"main": float(main[m].mean()), "cand": float(cand[m].mean()),
                   "change_pct": 100.0 * (cand[m].mean() / main[m].mean() - 1.0)}
    worse = int(sum(r["change_pct"] > 10.0 for r in records))
    out = {"pooled_main": float(main.mean()), "pooled_cand": float(cand.mean()),
           "pooled_change_pct": float(pooled), "generators": gens, "worse_10pct": worse,
           "a": bool(pooled <= -5.0), "b": bool(all(v["cand"] <= v["main"] for v in gens.values())),
           "c": bool(worse <= 3)}
    out["step1_passes"] = out["a"] and out["b"] and out["c"]
    return out


def markdown(records: list[dict], v: dict, command: str) -> str:
    lines = [f"`{command}`", "",
             "| generator | window | main MAE [K] | candidate MAE [K] | change | weights (final refit) "
             "| parts kept main / candidate |", "|---|---|---|---|---|---|---|"]
    for r in records:
        w = r["weights"]
        lines.append(f"| {r['generator']} | {r['window']} | {r['main']['mae']:.3f} | "
                     f"{r['cand']['mae']:.3f} | {r['change_pct']:+.1f} % | "
                     f"{w['w_min']:.2f}–{w['w_max']:.2f} | {', '.join(r['main']['kept']) or '-'}"
                     f" / {', '.join(r['cand']['kept']) or '-'} |")
    lines.append("")
    for g, s in v["generators"].items():
        lines.append(f"{g}: mean {s['main']:.3f} → {s['cand']:.3f} K ({s['change_pct']:+.1f} %).")
    lines.append(f"Pooled: {v['pooled_main']:.3f} → {v['pooled_cand']:.3f} K "
                 f"({v['pooled_change_pct']:+.1f} %); windows worse by > 10 %: {v['worse_10pct']}.")
    lines.append(f"(a) pooled falls >= 5 %: {'pass' if v['a'] else 'FAIL'}; (b) neither generator "
                 f"rises: {'pass' if v['b'] else 'FAIL'}; (c) <= 3 windows worse by > 10 %: "
                 f"{'pass' if v['c'] else 'FAIL'}. Step 1 "
                 f"{'passes' if v['step1_passes'] else 'fails'}.")
    cpu_m = sum(r["main"]["cpu_s"] for r in records)
    cpu_c = sum(r["cand"]["cpu_s"] for r in records)
    lines.append(f"Calibration CPU: main {cpu_m:.0f} s, candidate {cpu_c:.0f} s.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generators", default=",".join(DEV))
    ap.add_argument("--windows", default=None, help="default: the suite's 10 effect-free windows")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="out/cw")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    windows = a.windows.split(",") if a.windows else [*MAIN_WINDOWS, *EXTRA_WINDOWS]
    records = []
    for g in a.generators.split(","):
        for w in windows:
            records.append(run_window(g, w, a.seed))
            r = records[-1]
            print(f"{g}/{w}: main {r['main']['mae']:.3f} cand {r['cand']['mae']:.3f} K "
                  f"({r['change_pct']:+.1f} %)", file=sys.stderr, flush=True)
            (out / "shift_study.json").write_text(json.dumps({"windows": records}, indent=1))
    v = verdict(records)
    command = "python tests/generality/shift_study.py " + " ".join(argv or sys.argv[1:])
    (out / "shift_study.json").write_text(json.dumps({"windows": records, "verdict": v},
                                                     indent=1))
    text = markdown(records, v, command.strip())
    (out / "shift_study.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What each driver of the weather outlook costs, and the outlook's candidate changes, on the
kept dev replays (issue 10, item 3; the ol rule is stated in docs/effects.md "The
outlook's drivers, one at a time").

The estimator's loop never reads the outlook (gateway/estimate/replay.py builds the blocks after
it), so a replay kept by ``forecasts.py --keep`` and rescored with new blocks gives what a whole
replay with that outlook gives. Two sets:

- ``swaps`` (not causal, analysis only): ``clear-sky-trend`` with one driver at a time replaced
  by what was measured later (radiation, outside temperature, outside RH, wind; ``cloud``: the
  estimator's cloud fraction at each coming row instead of the start's held), and all of them;
- ``candidates`` (causal): the outlook's candidate settings (``CANDIDATES``).

Each variant's results go to ``DIR/<variant>.json`` in forecasts.py's format (for
compare_forecasts.py and outlook_rule.py); the table of ``corrected_outlook`` is printed.

    .venv/bin/python tests/generality/outlook_costs.py out/ol/main-keep --set swaps --out out/ol/swaps
    .venv/bin/python tests/generality/outlook_costs.py out/ol/main-keep --set candidates --out out/ol/cand
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.estimate.clear_sky_trend import ClearSkyTrend  # noqa: E402
from gateway.estimate.horizon import HorizonDrivers, outlook_drivers  # noqa: E402
from gateway.estimate.replay import HORIZONS, steps_of  # noqa: E402
from gateway.greenhouse import Site  # noqa: E402
from gateway.kitcsv import COLUMNS  # noqa: E402
from gateway.model.drivers import prepare_drivers  # noqa: E402
from gateway.series import Series  # noqa: E402
from tests.generality.forecasts import rescore  # noqa: E402
from tests.generality.outlook_variants import IndexBlend, Measured, ShapeVariant  # noqa: E402

SWAPS: dict[str, tuple[str, ...]] = {
    "i_glob": ("i_glob",), "t_out": ("t_out",), "rh_out": ("rh_out",), "wind": ("wind",),
    "cloud": (), "all": ("i_glob", "t_out", "rh_out", "wind")}
"""Swap → the kit columns replaced by the measured future (``cloud`` and ``all`` also take the
cloud fraction of the coming rows)."""
CANDIDATES: dict[str, Callable[[Site], ClearSkyTrend]] = {
    "index-blend": lambda site: IndexBlend(site, 86400.0, 3600.0),
    "shape-by-index": lambda site: ShapeVariant(site, shape_by_index=True),
    "shape-weight-online": lambda site: ShapeVariant(site, shape_memory=86400.0),
}
"""Candidate → its outlook for a site: the clear-sky index relaxed toward its last day's value
with a 60-min e-folding lead time (radiation, outlook_variants.IndexBlend: Yang 2019); each
earlier day's outside-temperature change scaled by the ratio of the clear-sky indices
(outlook_variants.sky_scale: Dai et al. 1999); the daily shape's weight per lead time learnt
over the last day of matured pairs (outlook_variants.ShapeVariant.shape_weights: Yang 2019)."""


def _blocks(res, outlook, cloud_ahead: bool = False) -> HorizonDrivers:
    """The outlook's blocks of a kept replay, as replay makes them (``outlook_drivers``), or with
    the estimator's cloud fraction of each coming row (not causal) for ``cloud_ahead``."""
    n, horizon = len(res.time), max(steps_of(HORIZONS, res.dt).values())
    kit = [c for c in COLUMNS if c in res.x]
    starts = np.arange(max(n - 1, 0))
    got = outlook_drivers(outlook, res.x, kit, res.time, res.dt, res.gh, starts, horizon)
    if not cloud_ahead:
        return got
    hist = {c: np.asarray(res.x[c], float) for c in kit}
    ahead = outlook.drivers_at(hist, res.time, np.arange(n), horizon, res.dt)
    cloud = np.asarray(res.x["cloud"], float)
    step = np.timedelta64(int(round(res.dt)), "s")
    width = horizon + 1
    for k in range(1, horizon + 1):
        cols = {c: v[:, k - 1] for c, v in ahead.items()}
        future = cloud[np.minimum(np.arange(n) + k, n - 1)]  # the cloud that came, row by row
        xk = prepare_drivers(Series(res.time + k * step, res.dt, cols), res.gh, cloud=future)
        for name in got.x:
            if name in xk:
                got.x[name][np.arange(len(starts)) * width + k] = np.asarray(xk[name], float)[starts]
    return got


def variants(which: str) -> dict[str, Callable]:
    """Variant → ``blocks(res)`` for forecasts.rescore."""
    out: dict[str, Callable] = {"now": lambda res: _blocks(res, ClearSkyTrend(res.gh.site))}
    if which == "swaps":
        for name, cols in SWAPS.items():
            out[name] = (lambda res, cols=cols, name=name: _blocks(
                res, Measured(ClearSkyTrend(res.gh.site), cols), name in ("cloud", "all")))
    else:
        for name, make in CANDIDATES.items():
            out[name] = lambda res, make=make: _blocks(res, make(res.gh.site))
    return out


def table(results: dict[str, list[dict]]) -> str:
    """corrected_outlook at 15 / 30 / 60 min per window, the mean over the 18 cells of MAE /
    persistence, its change from ``now`` and the outlook goals met (≤ 0.8 × persistence at 30
    and 60 min)."""
    def cells(rs: list[dict]) -> dict[str, dict[str, dict]]:
        return {f"{r['case']['generator']} {r['case']['window']}": r["horizons"] for r in rs}

    now = cells(results["now"])
    wins = list(now)
    lines = ["| variant | " + " | ".join(f"{w} 15 / 30 / 60" for w in wins)
             + " | mean MAE / persistence | vs now | outlook goals |", "|" + " --- |" * (len(wins) + 4)]
    base = None
    for label, rs in results.items():
        per, row, ratios, met = cells(rs), [], [], 0
        for w in wins:
            hs = per[w]
            row.append(" / ".join(f"{hs[h]['corrected_outlook']['mae']:.3f}" for h in hs))
            ratios += [hs[h]["corrected_outlook"]["mae"] / hs[h]["persistence"]["mae"] for h in hs]
            met += all(hs[h]["corrected_outlook"]["mae"] <= 0.8 * hs[h]["persistence"]["mae"]
                       for h in hs if int(h) >= 30)
        mean = float(np.mean(ratios))
        base = mean if base is None else base
        lines.append(f"| {label} | " + " | ".join(row) + f" | {mean:.4f} | "
                     f"{100 * (mean / base - 1):+.2f} % | {met} / {len(wins)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kept", help="replays pickled by forecasts.py --keep")
    ap.add_argument("--set", choices=("swaps", "candidates"), default="swaps")
    ap.add_argument("--out", required=True, help="directory of the per-variant JSON files")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for label, blocks in variants(a.set).items():
        t0 = time.perf_counter()
        results[label] = rescore(Path(a.kept), blocks)
        meta = {"command": f"tests/generality/outlook_costs.py --set {a.set} ({label})",
                "minutes": (time.perf_counter() - t0) / 60.0}
        (out / f"{label}.json").write_text(json.dumps({"meta": meta, "results": results[label]},
                                                      indent=1) + "\n", encoding="utf-8")
        print(f"  {label}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

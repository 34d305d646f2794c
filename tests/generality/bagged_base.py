"""Step 1 of the bg rule (issue 10; the rule is stated in docs/effects.md, "A bagged base"):
the base's held-out free-run MAE on the dev generators' effect-free windows (refsim, twonode x
the suite's 10 windows, seed 1), main's calibration and a bagged one side by side in one
process on the same code.

Main: search.prepare, as the diagnosis calibrates its base. Candidate: K = 5 bags; bag b draws
the calibration part's whole days (days since the first row) with replacement (numpy
default_rng(b), as many draws as days), and base.calibrate_base runs exactly as in prepare
(same seed, bounds, iterations, structure choice) with every set of shooting windows it uses
(fits on C1, inner validation on C2, refit on C) cut to the windows that start on drawn days,
each repeated as often as its day was drawn (``resample``). The candidate's held-out prediction
is the mean of the 5 bags' free runs. The MAE is the diagnosis's "base" figure (search._report's
``before``, the suite's "base MAE"): free runs on the data's own grid restarted at each held-out
block, |measured − model| averaged over the held-out rows; the fit grid's figure
(day_residual.py's ``heldout_mae``) is reported beside it. The search is not run (the figure
does not depend on it). Never the held-out generator.

    PYTHONPATH=. nice -n 5 python tests/generality/bagged_base.py [--out out/bg]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import EXTRA_WINDOWS, Case, case_series  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402
from tests.generality.report import MAIN_WINDOWS  # noqa: E402

DEV = ("refsim", "twonode")
K_BAGS = 5
DAY_S = 86400.0
SHORT = {"vent controller": "V", "long-wave sky loss": "L", "heat store": "S",
         "sensor offset": "O", "night sky level": "N"}
"""Abbreviations of the optional parts in the table."""


def day_counts(n_days: int, seed: int) -> np.ndarray:
    """How often each of ``n_days`` days was drawn: ``n_days`` draws with replacement."""
    draws = np.random.default_rng(seed).integers(0, n_days, n_days)
    return np.bincount(draws, minlength=n_days)


def day_resample(counts: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
    """Window starts (rows on a grid of ``dt`` [s]) → those on drawn days, each repeated as often
    as its day was drawn (calibrate_base's ``resample``)."""
    def pick(starts: np.ndarray) -> np.ndarray:
        day = (np.asarray(starts) * dt // DAY_S).astype(int)
        return np.repeat(starts, counts[day]).astype(int)
    return pick


def heldout_mae(model, theta, st, series, xf, gh) -> tuple[np.ndarray, np.ndarray]:
    """The base's held-out free run on the data's grid (as search._report's ``before``) and on
    the fit grid (as the search's state holds it)."""
    from gateway.diagnose import judge as jd

    k, held = series_k(series, st), st.held
    nf, sf = len(series), st.ctx.split * k
    ffolds = [[(a * k, b * k if b < held.n else nf) for a, b in f] for f in held.folds]
    fine = jd.heldout(model, [theta, theta], xf, gh, series.step, ffolds, sf, nf)["free_run"]
    coarse = st.heldout(model, [theta, theta])["free_run"]
    return fine, coarse


def series_k(series, st) -> int:
    return int(round(st.ctx.dt / series.step))


def mae(meas: np.ndarray, pred: np.ndarray) -> float:
    return float(np.nanmean(np.abs(meas - pred)))


def timed_prepare(series, gh, model):
    """search.prepare, as the diagnosis runs it, and the CPU seconds of its calibrate_base."""
    from gateway.diagnose import search

    spent: list[float] = []
    inner = search.calibrate_base

    def timed(*args, **kwargs):
        t0 = time.process_time()
        out = inner(*args, **kwargs)
        spent.append(time.process_time() - t0)
        return out

    search.calibrate_base = timed
    try:
        start = search.prepare(series, gh, model)
    finally:
        search.calibrate_base = inner
    return start, spent[0]


def kept_parts(log: list[dict]) -> list[str]:
    return [r["structure"] for r in log if r["kept"] and r["structure"] != "base"]


def refit_only(model, theta, gh, ctx, resample: Callable[[np.ndarray], np.ndarray]):
    """Main's chosen structure refitted on the bag's windows of the whole calibration part, as
    calibrate_base's last step (Levenberg–Marquardt from main's parameters): a bag without its
    own structure choice (``--fixed-structure``)."""
    from gateway.diagnose.base import fit
    from gateway.diagnose.fit import Shooting, window_starts

    whole = resample(window_starts([(0, ctx.split)], ctx.horizon, skip=ctx.horizon))
    shoot = Shooting(model, ctx.x, gh, ctx.dt, whole, ctx.horizon)
    return model, fit(model, theta, shoot, gh, 0, 0), [{"structure": "fixed", "kept": False}]


def forced_structure(model, gh, ctx, keep: set[str]):
    """calibrate_base as the diagnosis runs it, every step the same, except that an optional
    part is kept iff its label is in ``keep`` (``--vote-from``: the structure the bags voted
    for, fitted on C1 and refitted on all of C as the chosen structure is)."""
    from gateway.diagnose import base

    current: list[str] = []
    inner_options, inner_dbic = base.options, base.delta_bic

    def labelled(m, g):
        out = []
        for label, build in inner_options(m, g):
            def tracked(mm, _build=build, _label=label):
                current.append(_label)
                return _build(mm)
            out.append((label, tracked))
        return out

    base.options = labelled
    base.delta_bic = lambda *a: -1.0 if current and current[-1] in keep else 1.0
    inner_validated = base._validated
    base._validated = lambda new, old: bool(current and current[-1] in keep)
    try:
        return base.calibrate_base(model, gh, ctx.x, ctx.dt, ctx.split, ctx.horizon, 0,
                                   lambda msg: None)
    finally:
        base.options, base.delta_bic, base._validated = inner_options, inner_dbic, inner_validated


def tried_models(model, gh, ctx) -> list[tuple]:
    """Every (model, parameters) main's calibrate_base fits on C1 (the base, then each option
    tried on top of the parts kept so far), each refitted on all of C (``--tried-average``)."""
    from gateway.diagnose import base
    from gateway.diagnose.fit import Shooting, window_starts

    seen: list[tuple] = []
    inner_fit = base.fit

    def recording(m, theta, shoot, g, iterations, seed):
        out = inner_fit(m, theta, shoot, g, iterations, seed)
        seen.append((m, out))
        return out

    base.fit = recording
    try:
        base.calibrate_base(model, gh, ctx.x, ctx.dt, ctx.split, ctx.horizon, 0, lambda msg: None)
    finally:
        base.fit = inner_fit
    whole = window_starts([(0, ctx.split)], ctx.horizon, skip=ctx.horizon)
    return [(m, inner_fit(m, th, Shooting(m, ctx.x, gh, ctx.dt, whole, ctx.horizon), gh, 0, 0))
            for m, th in seen[:-1]]  # the last fit is the chosen structure's refit on C


def structure_parts(model) -> list[str]:
    """The optional parts of a fitted base (labels as the structure log's)."""
    from gateway.diagnose.base import structure_detail

    detail = structure_detail(model)
    return [label for label in SHORT if label in detail]


def voted(record: dict, bags: int = K_BAGS) -> set[str]:
    """The parts kept by a majority of a run's bags (a record of the rule-bg JSON)."""
    counts: dict[str, int] = {}
    for bag in record["cand"]["bags"]:
        for part in bag["kept"]:
            counts[part] = counts.get(part, 0) + 1
    return {p for p, n in counts.items() if 2 * n > bags}


@dataclass
class Window:
    """One effect-free window with main's base calibrated as the diagnosis does."""

    gh: object
    model: object
    start: object  # search.prepare's result
    cpu_main: float

    @property
    def ctx(self):
        return self.start.state.ctx


Fit = tuple[object, np.ndarray, dict]
"""A candidate base: (model, parameters, what the table says of it: ``kept``, ``seed``, ...)."""


def bag_fits(w: Window, bags: int = K_BAGS, first_bag: int = 0,
             fixed_structure: bool = False) -> list[Fit]:
    """The rule's bags (seeds ``first_bag`` onwards); ``fixed_structure``: each bag refits main's
    structure only (:func:`refit_only`)."""
    from gateway.diagnose.base import calibrate_base

    ctx, st = w.ctx, w.start.state
    n_days = int(np.ceil(ctx.split * ctx.dt / DAY_S - 1e-9))
    out = []
    for b in range(first_bag, first_bag + bags):
        counts = day_counts(n_days, b)
        pick = day_resample(counts, ctx.dt)
        if fixed_structure:
            m_b, th_b, log_b = refit_only(st.model0, w.start.theta, w.gh, ctx, pick)
        else:
            m_b, th_b, log_b = calibrate_base(w.model, w.gh, ctx.x, ctx.dt, ctx.split,
                                              ctx.horizon, 0, lambda msg: None, pick)
        out.append((m_b, th_b, {"seed": b, "day_counts": counts.tolist(),
                                "kept": kept_parts(log_b)}))
    return out


def vote_fits(w: Window, keep: set[str]) -> list[Fit]:
    """The one structure the bags voted for (:func:`forced_structure`)."""
    m_v, th_v, log_v = forced_structure(w.model, w.gh, w.ctx, keep)
    return [(m_v, th_v, {"seed": None, "kept": kept_parts(log_v)})]


def tried_fits(w: Window) -> list[Fit]:
    """Every structure main's calibration tried, refitted on C (:func:`tried_models`)."""
    return [(m, th, {"seed": None, "kept": structure_parts(m)})
            for m, th in tried_models(w.model, w.gh, w.ctx)]


def compare_window(generator: str, window: str, seed: int,
                   candidates: Callable[[Window], list[Fit]]) -> dict:
    """Main's base and the mean of the ``candidates``' free runs on one effect-free window:
    held-out MAE of each, the candidates' CPU time, what each kept."""
    from gateway.diagnose.fit import drivers

    if generator in HELD_OUT:
        raise SystemExit(f"{generator} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = case_series(Case("diagnose", generator, window, "none", seed),
                                           Path(tmp))
    start, cpu_main = timed_prepare(series, gh, model)
    w, st = Window(gh, model, start, cpu_main), start.state
    xf = drivers(series, gh)
    meas_f = xf["t_in"][w.ctx.split * series_k(series, st):]
    meas_c = w.ctx.x["t_in"][w.ctx.split:]
    fine0, coarse0 = heldout_mae(st.model0, start.theta, st, series, xf, gh)
    t0 = time.process_time()
    fits = candidates(w)
    cpu = time.process_time() - t0
    runs = [heldout_mae(m, th, st, series, xf, gh) for m, th, _ in fits]
    each = [info | {"mae": mae(meas_f, fine)} for (_, _, info), (fine, _) in
            zip(fits, runs, strict=True)]
    rec = {"generator": generator, "window": window,
           "calibration_days": w.ctx.split * w.ctx.dt / DAY_S,
           "main": {"mae": mae(meas_f, fine0), "mae_fit_grid": mae(meas_c, coarse0),
                    "kept": kept_parts(start.structure), "cpu_s": cpu_main},
           "cand": {"mae": mae(meas_f, np.mean([r[0] for r in runs], axis=0)),
                    "mae_fit_grid": mae(meas_c, np.mean([r[1] for r in runs], axis=0)),
                    "cpu_s": cpu, "bags": each}}
    rec["change_pct"] = 100.0 * (rec["cand"]["mae"] / rec["main"]["mae"] - 1.0)
    return rec


def verdict(records: list[dict]) -> dict:
    """The rule's (a) pooled mean falls >= 5 %, (b) neither generator's mean is worse, (c) at
    most 3 of the windows worse by > 10 %."""
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


def _parts(kept: list[str]) -> str:
    return "+".join(SHORT.get(p, p) for p in kept) or "–"


def markdown(records: list[dict], v: dict, command: str) -> str:
    lines = [f"`{command}`", "",
             "| generator | window | main MAE [K] | bagged MAE [K] | change | single bags' mean MAE "
             "[K] | parts main / bags 0–4 |", "|---|---|---|---|---|---|---|"]
    for r in records:
        bags = r["cand"]["bags"]
        single = np.mean([b["mae"] for b in bags])
        lines.append(f"| {r['generator']} | {r['window']} | {r['main']['mae']:.3f} | "
                     f"{r['cand']['mae']:.3f} | {r['change_pct']:+.1f} % | {single:.3f} | "
                     f"{_parts(r['main']['kept'])} / "
                     + " ".join(_parts(b["kept"]) for b in bags) + " |")
    lines.append("")
    lines.append("Parts: V vent controller, L long-wave sky loss, S heat store, O sensor offset.")
    for g, s in v["generators"].items():
        lines.append(f"{g}: mean {s['main']:.3f} → {s['cand']:.3f} K ({s['change_pct']:+.1f} %).")
    lines.append(f"Pooled: {v['pooled_main']:.3f} → {v['pooled_cand']:.3f} K "
                 f"({v['pooled_change_pct']:+.1f} %); windows worse by > 10 %: {v['worse_10pct']}.")
    fit_m = np.mean([r["main"]["mae_fit_grid"] for r in records])
    fit_c = np.mean([r["cand"]["mae_fit_grid"] for r in records])
    lines.append(f"On the fit grid (day_residual.py's figure): pooled {fit_m:.3f} → {fit_c:.3f} K "
                 f"({100.0 * (fit_c / fit_m - 1.0):+.1f} %).")
    lines.append(f"(a) pooled falls >= 5 %: {'pass' if v['a'] else 'FAIL'}; (b) neither generator "
                 f"worse: {'pass' if v['b'] else 'FAIL'}; (c) <= 3 windows worse by > 10 %: "
                 f"{'pass' if v['c'] else 'FAIL'}. Step 1 "
                 f"{'passes' if v['step1_passes'] else 'fails'}.")
    cpu_m = sum(r["main"]["cpu_s"] for r in records)
    cpu_c = sum(r["cand"]["cpu_s"] for r in records)
    lines.append(f"Base calibration CPU over the windows: main {cpu_m:.0f} s, bagged {cpu_c:.0f} s "
                 f"(× {cpu_c / cpu_m:.2f}).")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generators", default=",".join(DEV))
    ap.add_argument("--windows", default=None, help="default: the suite's 10 effect-free windows")
    ap.add_argument("--seed", type=int, default=1, help="the generators' sensor seed (the suite's)")
    ap.add_argument("--first-bag", type=int, default=0,
                    help="seed of the first bag's day draw (the rule's: 0, bags 0-4)")
    ap.add_argument("--fixed-structure", action="store_true",
                    help="each bag refits main's chosen structure only (no structure choice)")
    ap.add_argument("--vote-from", default=None, metavar="JSON",
                    help="a bagged run's JSON: fit the one structure its bags' majority kept")
    ap.add_argument("--tried-average", action="store_true",
                    help="the mean of every structure main's calibration tried, each refitted on C")
    ap.add_argument("--out", default="out/bg")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    windows = a.windows.split(",") if a.windows else [*MAIN_WINDOWS, *EXTRA_WINDOWS]
    command = "python tests/generality/bagged_base.py " + " ".join(argv or sys.argv[1:])
    records: list[dict] = []
    t_all = time.perf_counter()
    for g in a.generators.split(","):
        for w in windows:
            t0 = time.perf_counter()
            if a.tried_average:
                build = tried_fits
            elif a.vote_from:
                prior = {(r["generator"], r["window"]): r
                         for r in json.loads(Path(a.vote_from).read_text())["windows"]}
                build = partial(vote_fits, keep=voted(prior[(g, w)]))
            else:
                build = partial(bag_fits, first_bag=a.first_bag,
                                fixed_structure=a.fixed_structure)
            records.append(compare_window(g, w, a.seed, build))
            r = records[-1]
            print(f"{g}/{w}: main {r['main']['mae']:.3f} bagged {r['cand']['mae']:.3f} K "
                  f"({r['change_pct']:+.1f} %; {time.perf_counter() - t0:.0f} s)",
                  file=sys.stderr, flush=True)
            (out / "bagged_base.json").write_text(json.dumps({"windows": records}, indent=1))
    v = verdict(records)
    meta = {"command": command.strip(), "wall_s": time.perf_counter() - t_all, "bags": K_BAGS,
            "first_bag": a.first_bag, "fixed_structure": a.fixed_structure}
    (out / "bagged_base.json").write_text(json.dumps({"windows": records, "verdict": v,
                                                      "meta": meta}, indent=1))
    text = markdown(records, v, command.strip())
    (out / "bagged_base.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

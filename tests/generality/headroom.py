"""Where the failing dev cases fail: a headroom taxonomy (docs/effects.md, "Where the failing
cases fail: headroom"). For every dev effect case (refsim, twonode × autumn, winter, summer ×
the 7 library kinds; heater and night_heater apart), with the RIGHT effect(s) for the kind
(generators.EXPECTED, those in the diagnosis's LIBRARY):

1. **alone**: the right effect(s) offered alone, the diagnosis's first round run on the
   calibrated base by the search's own code (``search.prepare``, ``search.search_round`` with
   ``every``: rank, per-fold fit, judge, pick; every candidate comes back, a rejected one with
   its held-out prediction too): the held-out free-run MAE cut against the base, the suite's
   own sign-flip p (``cases.own_significance``) and the judge's p, whether the judge keeps it,
   and start − truth of the start the search reports (``search.fit_all``, the finding's start).
2. **oracle**: the same effect with its start held at the injected one (``search.try_effect``
   with ``at``: base parameters and amplitude refitted per fold's fit set as the search refits
   them), its cut and p, and the judge's verdict on it. If this misses the 20 % cut or
   p < 0.05, the case cannot pass with the present base, whatever the search does.
3. the case's visible size (``cases.case_visible_change``) and the base's held-out MAE on the
   same window without the change.

Each case gets one class, first that applies: ``invisible`` (visible < cases.MIN_VISIBLE_K),
``unreachable`` (no right effect's oracle cuts ≥ 20 % with p < 0.05), ``start`` (the effect
alone's reported start > 12 h from the truth), ``weak`` (started right, but its fold fits cut
< 20 % where the oracle's do not), ``judge`` (started right, cut ≥ 20 %, but not kept by the
judge or the suite's p ≥ 0.05), ``rival`` (the effect alone passes everything, the full library
names another effect or none first: the verdict of the suite's results file, read only),
``pass``. Significance: ``--judge days`` (default: judge.DAY_TEST = True, as main ships it) or
``pieces``. Never the held-out generator.

    python tests/generality/headroom.py [--judge days|pieces] [--json out/generality/hr/hr.json]
        [--suite bench/results/generality.json] [--store] [refsim/autumn/drift ...]

All 42 cases: about 6 min on one core (one case: 4–20 s; each window's effect-free base once).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import (  # noqa: E402
    ALPHA,
    MIN_CUT,
    MIN_VISIBLE_K,
    START_TOLERANCE_H,
    Case,
    case_series,
    case_visible_change,
    own_significance,
)
from tests.generality.generators import EXPECTED, HELD_OUT, KINDS  # noqa: E402
from tests.generality.report import KIND_GROUPS, MAIN_WINDOWS  # noqa: E402

if TYPE_CHECKING:
    from gateway.diagnose.search import State, Tried

DEV = ("refsim", "twonode")
WINDOWS = MAIN_WINDOWS
GROUP = {k: g for g, ks in KIND_GROUPS.items() for k in ks}
"""The suite report's kind of each injected change (heater and night heater are one)."""
CLASSES = ("invisible", "unreachable", "start", "weak", "judge", "rival", "pass")
SUITE = ROOT / "bench" / "results" / "generality.json"
"""The suite's results (suite.py's default output): the full library's verdict per case."""
LEVER = {"invisible": "none (no method sees it)", "unreachable": "base error",
         "start": "start placement", "weak": "fit at the found start", "judge": "judge",
         "rival": "rival ranking", "pass": "-"}


@dataclass
class Setup:
    """One case as ``diagnose`` builds it before the search (``search.prepare``)."""

    data: object
    state: State  # the calibrated base, its held-out prediction, the folds
    time: np.ndarray
    truth: float | None  # injected start [s since the first row]


@dataclass
class Fit:
    """One right effect fitted per fold and judged on the held-out folds."""

    effect: str
    cut: float  # held-out free-run MAE cut against the base as calibrated
    p_suite: float | None  # cases.own_significance (sign flips over 6-h pieces)
    p_judge: float  # the judge's p (days or pieces, --judge)
    p_days: float
    p_pieces: float
    cut_reference: float
    judge_ok: bool  # the judge's rule (and ΔBIC < 0 on both folds' fit sets)
    fold_starts_h: list[float]
    why: str
    delta_bic: list[float]  # per fold's fit set (second output included)
    mse_after: float  # held-out free-run MSE with it (the judge's pick between two)
    rank_dbic: float | None = None  # ΔBIC of its τ scan on all data (tried only when < 0)
    start_h: float | None = None  # start − truth of the all-data fit (the reported start)


@dataclass
class Row:
    label: str
    generator: str
    window: str
    kind: str
    visible_k: float | None
    base_mae: float  # this case's base, held out [K]
    base_mae_free: float  # the same window without the change [K]
    alone: list[Fit] = field(default_factory=list)
    first: str | None = None  # the effect the round keeps (alone), None if none passes
    oracle: list[Fit] = field(default_factory=list)
    full: dict = field(default_factory=dict)  # the suite's verdict with the whole library
    cls: str = ""
    seconds: float = 0.0


def right_effects(kind: str, store: bool = False) -> list:
    """The library effects that name ``kind`` (generators.EXPECTED ∩ the diagnosis's LIBRARY;
    with ``store`` also the added heat store, which LIBRARY does not offer by default)."""
    from gateway.diagnose.effects import HEAT_STORE, LIBRARY

    return [e for e in (*LIBRARY, *((HEAT_STORE,) if store else ())) if e.name in EXPECTED[kind]]


def setup(generator: str, window: str, kind: str) -> Setup:
    """Data, calibrated base and folds of one case, as ``diagnose`` makes them (split 0.5,
    seed 0: ``search.prepare``)."""
    from gateway.diagnose import search

    if generator in HELD_OUT:
        raise SystemExit(f"{generator} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        data, gh, model, series = case_series(Case("diagnose", generator, window, kind), Path(tmp))
    start = search.prepare(series, gh, model)
    truth = (float((data.start - start.coarse.time[0]) / np.timedelta64(1, "s"))
             if data.start is not None else None)
    return Setup(data, start.state, start.coarse.time, truth)


def mae(su: Setup, pred: dict) -> float:
    m = su.state.ctx.x["t_in"][su.state.ctx.split:]
    e = np.abs(pred["free_run"] - m)
    return float(np.nanmean(e))


def judged(su: Setup, t: Tried) -> Fit:
    """The held-out figures of a candidate the search tried (``search.Tried``: its effect added
    to the base, fitted per fold, judged against the base refitted per fold)."""
    ctx, st, v = su.state.ctx, su.state, t.verdict
    m = ctx.x["t_in"][ctx.split:]
    eb, ea = np.abs(st.current_pred["free_run"] - m), np.abs(t.pred["free_run"] - m)
    ok = np.isfinite(eb) & np.isfinite(ea)
    ns = SimpleNamespace(split_index=ctx.split, measured=ctx.x["t_in"], time=su.time,
                         pred_before=st.current_pred, pred_after=t.pred)
    return Fit(t.effect.name, float(1.0 - ea[ok].mean() / eb[ok].mean()), own_significance(ns),
               float(v.p), float(v.stats["p_days"]), float(v.stats["p_pieces"]),
               float(v.stats["cut_reference"]), t.passed,
               [(x - su.truth) / 3600.0 for x in t.starts], v.why, list(v.delta_bic),
               float(v.mse_after), t.rank_dbic)


def alone(su: Setup, effects: list) -> tuple[list[Fit], str | None, dict]:
    """The diagnosis's first round with only ``effects`` offered (``search.search_round``, all
    of them tried: the ranking's ΔBIC noted, an effect the search would not try, ΔBIC ≥ 0,
    never passes), each one's reported start from its all-data fit (``search.fit_all``); the
    effect the round keeps, and the judge's reference prediction (for ``oracle``)."""
    from gateway.diagnose import search

    st = su.state
    r = search.search_round(st, effects, tries=None, every=True)
    out = []
    for t in r.tried:
        fit = judged(su, t)
        full = search.fit_all(st, t)
        fit.start_h = (float(full.theta[t.model.index(t.effect.tau_name)]) - su.truth) / 3600.0
        out.append(fit)
    return out, (r.best.effect.name if r.best is not None else None), r.reference


def oracle(su: Setup, e, ref_pred: dict) -> Fit:
    """``e`` with its start held at the injected one, fitted per fold's fit set and judged
    (``search.try_effect`` with ``at``)."""
    from gateway.diagnose import search

    fit = judged(su, search.try_effect(su.state, e, ref_pred, at=su.truth))
    fit.start_h = 0.0
    return fit


@lru_cache(maxsize=8)
def base_mae_free(generator: str, window: str) -> float:
    """The base's held-out free-run MAE [K] on the window without any change."""
    su = setup(generator, window, "none")
    return mae(su, su.state.current_pred)


def passes(f: Fit) -> bool:
    return f.cut >= MIN_CUT and f.p_suite is not None and f.p_suite < ALPHA


def classify(row: Row) -> str:
    """The first class of the module docstring that applies."""
    if row.visible_k is not None and row.visible_k < MIN_VISIBLE_K:
        return "invisible"
    if not any(passes(f) for f in row.oracle):
        return "unreachable"
    f = lead(row)
    if f.start_h is None or abs(f.start_h) > START_TOLERANCE_H:
        return "start"
    if f.cut < MIN_CUT:
        return "weak"
    if not (f.judge_ok and passes(f)):
        return "judge"
    return "pass" if row.full.get("ok") else "rival"


def lead(row: Row) -> Fit:
    """The effect alone that speaks for the case: the one the round keeps, else the one with
    the largest cut."""
    kept = [f for f in row.alone if f.effect == row.first]
    return kept[0] if kept else max(row.alone, key=lambda f: f.cut)


def full_verdict(suite: dict, generator: str, window: str, kind: str) -> dict:
    for r in suite.get("results", []):
        c = r["case"]
        if (c["task"], c["generator"], c["window"], c["kind"]) == ("diagnose", generator, window,
                                                                   kind):
            first = r["findings"][0]["effect"] if r.get("findings") else None
            return {"first": first, "ok": bool(r["verdict"]["ok"]),
                    "start_error_h": r.get("start_error_h"), "cut": r.get("cut"),
                    "p": r.get("p_value")}
    return {}


def study(label: str, suite: dict, store: bool = False) -> Row:
    t0 = time.perf_counter()
    g, w, k = label.split("/")
    su = setup(g, w, k)
    effects = right_effects(k, store)
    fits, first, ref_pred = alone(su, effects)
    row = Row(label, g, w, k, case_visible_change(Case("diagnose", g, w, k), su.data),
              mae(su, su.state.current_pred), base_mae_free(g, w), fits, first,
              [oracle(su, e, ref_pred) for e in effects], full_verdict(suite, g, w, k))
    row.cls = classify(row)
    row.seconds = time.perf_counter() - t0
    return row


def _p(p: float | None) -> str:
    return "-" if p is None else f"{p:.3f}"


def markdown(rows: list[Row]) -> str:
    """One line per case, then the count per class."""
    out = ["| case | visible [K] | base MAE case / effect-free [K] | alone: effect, start − truth "
           "[h], cut, p suite / judge, kept | oracle (true start): cut, p suite / judge, judge ok "
           "| full library first | class |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        a = lead(r)
        o = max(r.oracle, key=lambda f: f.cut)
        start = "-" if a.start_h is None else f"{a.start_h:+.1f}"
        out.append(
            f"| {r.label} | {r.visible_k:.2f} | {r.base_mae:.2f} / {r.base_mae_free:.2f} | "
            f"{a.effect} {start}, {100 * a.cut:+.0f} %, {_p(a.p_suite)} / {_p(a.p_judge)}, "
            f"{'kept' if r.first else 'not kept'} | {o.effect} {100 * o.cut:+.0f} %, "
            f"{_p(o.p_suite)} / {_p(o.p_judge)}, {'yes' if o.judge_ok else 'no'} | "
            f"{r.full.get('first') or 'none'} | **{r.cls}** |")
    out += ["", *best_case(rows)]
    out += ["", "| class | cases | lever | " + " | ".join(f"{g}/{w}" for g in DEV for w in WINDOWS)
            + " |", "| --- | --- | --- | " + " | ".join("---" for _ in DEV for _ in WINDOWS) + " |"]
    for c in CLASSES:
        per = [sum(r.cls == c for r in rows if (r.generator, r.window) == (g, w))
               for g in DEV for w in WINDOWS]
        out.append(f"| {c} | {sum(per)} | {LEVER[c]} | " + " | ".join(map(str, per)) + " |")
    return "\n".join(out)


def kind_ok(rows: list[Row], test) -> int:
    """Kinds (of the 6: heater and night_heater count as one, passing when both do) whose cases
    all meet ``test``."""
    by: dict[str, list[bool]] = {}
    for r in rows:
        by.setdefault(GROUP[r.kind], []).append(test(r))
    return sum(all(v) for v in by.values())


def oracle_ok(r: Row, judge: bool) -> bool:
    """A right effect at the true start meets the suite's bar (and, with ``judge``, the judge
    keeps it: the diagnosis would report it)."""
    return any(passes(f) and (f.judge_ok or not judge) for f in r.oracle)


def best_case(rows: list[Row]) -> list[str]:
    """Per window: kinds passing, and at best with a perfect search (the right effect at the
    true start) on the present base, by the suite's bar alone and with the judge keeping it."""
    out = ["| window | kinds passing | perfect search: meets the suite's bar | ... and kept by the "
           "judge |", "| --- | --- | --- | --- |"]
    for g in DEV:
        for w in WINDOWS:
            rs = [r for r in rows if (r.generator, r.window) == (g, w)]
            if not rs:
                continue
            n = len({GROUP[r.kind] for r in rs})
            out.append(f"| {g}/{w} | {kind_ok(rs, lambda r: r.cls == 'pass')}/{n} | "
                       f"{kind_ok(rs, lambda r: oracle_ok(r, False))}/{n} | "
                       f"{kind_ok(rs, lambda r: oracle_ok(r, True))}/{n} |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", help="generator/window/kind (default: all 42 dev cases)")
    ap.add_argument("--judge", choices=["days", "pieces"], default="days",
                    help="the judge's significance unit (judge.DAY_TEST; default days)")
    ap.add_argument("--suite", default=str(SUITE),
                    help="the suite's results file, for the full library's verdict (pass or rival); "
                         "default bench/results/generality.json")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument("--store", action="store_true",
                    help="thermal_mass: offer the added heat store too (not in LIBRARY by default)")
    a = ap.parse_args(argv)
    from gateway.diagnose import judge as jd

    jd.DAY_TEST = a.judge == "days"
    labels = a.cases or [f"{g}/{w}/{k}" for g in DEV for w in WINDOWS for k in KINDS]
    if any(lb.split("/")[0] in HELD_OUT for lb in labels):
        ap.error(f"{', '.join(HELD_OUT)} is held out: dev generators only ({', '.join(DEV)})")
    if not Path(a.suite).exists():
        ap.error(f"{a.suite}: no suite results (make bench-generality, or --suite FILE)")
    suite = json.loads(Path(a.suite).read_text(encoding="utf-8"))
    missing = [lb for lb in labels if not full_verdict(suite, *lb.split("/"))]
    if missing:
        ap.error(f"{a.suite} has no verdict for {', '.join(missing)}")
    rows = []
    for label in labels:
        r = study(label, suite, a.store)
        rows.append(r)
        print(f"{label}: {r.cls} ({r.seconds:.0f} s)", flush=True)
        if a.json:
            _write(Path(a.json), rows, a)
    print(markdown(rows))
    return 0


def _write(path: Path, rows: list[Row], a) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"judge": a.judge, "suite": a.suite, "store": a.store, "when": time.strftime("%Y-%m-%d %H:%M UTC",
                                                                        time.gmtime())}
    path.write_text(json.dumps({"meta": meta, "rows": [asdict(r) for r in rows]}, indent=1) + "\n",
                    encoding="utf-8")


if __name__ == "__main__":
    raise SystemExit(main())

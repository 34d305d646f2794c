"""Study: the judge's significance test under day-scale dependence (docs/effects.md, "Day-scale
dependence: the piece test's real size, and a test on days").

    python tests/generality/day_test_study.py size [--test day_p] [--draws 4000]
    python tests/generality/day_test_study.py power
    python tests/generality/day_test_study.py null --out out/generality/jd/null_trials.jsonl
    python tests/generality/day_test_study.py cases refsim/autumn/ventilation ...
    python tests/generality/day_test_study.py rho out/generality/jd/null_trials.jsonl
    python tests/generality/day_test_study.py short [--days 6 --at 3.6]   # ~10 min

``size``/``power``: ``significance.paired_p`` or ``significance.day_p`` on synthetic piece differences (a
day effect, AR(1) across days, plus piece noise; seeded). ``null``: the dev suite's 20
effect-free windows (refsim, twonode), every judged candidate with both p-values and its day
means, and the base's held-out day means (one JSON line per window, then a summary). ``cases``:
the same for named suite cases. ``rho``: ``day_p`` of the logged day means at several
``DAY_RHO``. ``short``: the 12 model-made cases of tests/diagnose_cases.py (reference
simulator, 6 effects x 2 models) at ``--days`` with the change at ``--at``, each diagnosed with
the piece test and with the day test: what the day test costs on short records. Otherwise the
judge's switch is as imported (``judge.DAY_TEST``: on since 2026-11-27).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.diagnose import judge as jd  # noqa: E402
from gateway.diagnose import significance as sig  # noqa: E402

RHOS = (0.0, 0.2, 0.3, 0.4, 0.5)


def day_null(rng: np.random.Generator, days: int, phi_d: float, share: float,
             per: int = 4) -> np.ndarray:
    """Null piece differences of unit variance: a day effect (AR(1) across days, ``phi_d``)
    carrying ``share`` of the variance, shared by the day's ``per`` pieces, plus piece noise."""
    u = np.empty(days)
    u[0] = rng.normal()
    for k in range(1, days):
        u[k] = phi_d * u[k - 1] + np.sqrt(1 - phi_d**2) * rng.normal()
    return np.sqrt(share) * np.repeat(u, per) + np.sqrt(1 - share) * rng.normal(size=days * per)


def p_of(test: str, d: np.ndarray) -> float:
    return sig.paired_p(d) if test == "paired_p" else sig.day_p(d, np.arange(len(d)) // 4)


def size(test: str, draws: int) -> None:
    print(f"{test}: share of p <= 0.05 on null differences, {draws} seeded draws")
    print("days share  phi_d=0.0     0.3     0.5     0.7")
    for days in (7, 5):
        for share in (0.3, 0.6, 0.9):
            row = []
            for phi in (0.0, 0.3, 0.5, 0.7):
                rng = np.random.default_rng(100 + int(10 * phi) + days)
                p = np.array([p_of(test, day_null(rng, days, phi, share)) for _ in range(draws)])
                row.append(float(np.mean(p <= 0.05)))
            print(f"{days:4d} {share:5.1f} " + " ".join(f"{x:9.3f}" for x in row))


def power(draws: int) -> None:
    print("cut/scatter days phi_d paired_p  day_p   (share 0.6; p <= 0.05)")
    for days in (7, 4):
        for phi in (0.0, 0.5):
            for eff in (0.5, 1.0, 1.5, 2.0, 3.0):
                rng = np.random.default_rng(7 + days)
                ds = [eff + day_null(rng, days, phi, 0.6) for _ in range(draws)]
                a = np.mean([p_of("paired_p", d) <= 0.05 for d in ds])
                b = np.mean([p_of("day_p", d) <= 0.05 for d in ds])
                print(f"{eff:11.1f} {days:4d} {phi:5.1f} {a:8.3f} {b:6.3f}")


def diagnose_case(label: str) -> dict:
    """One suite case (generator/window[/kind]) diagnosed: its findings, trials and the base's
    held-out day means of prediction - reading."""
    from gateway.diagnose import diagnose
    from tests.generality.cases import Case, _series

    g, w, *k = label.split("/")
    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = _series(Case("diagnose", g, w, k[0] if k else "none"), Path(tmp))
        d = diagnose(series, gh, model)
    s = d.split_index
    err = d.pred_before["free_run"] - d.measured[s:]
    day = ((d.time[s:] - d.time[0]) / np.timedelta64(1, "D")).astype(int)
    ok = np.isfinite(err)
    return {"case": label, "findings": [f.effect.name for f in d.findings],
            "base_day_means": [float(err[ok & (day == j)].mean()) for j in np.unique(day[ok])],
            "trials": d.trials, "seconds": d.seconds}


def pooled_r(series: list[list[float]]) -> tuple[float, float]:
    """Lag-1 autocorrelation pooled over series (each about its mean): raw and with Kendall's
    small-sample correction (1 + 4r)/n at the mean length."""
    num = den = 0.0
    for x in series:
        z = np.asarray(x) - np.mean(x)
        num, den = num + float(z[1:] @ z[:-1]), den + float(z @ z)
    r = num / den
    return r, r + (1 + 4 * r) / np.mean([len(x) for x in series])


def trial_line(label: str, t: dict) -> str:
    return (f"{label:30s} r{t['round']} {t['effect']:22s} cut {t['cut']:+.2f} ref "
            f"{t['cut_reference']:+.2f} p_pieces {t['p_pieces']:.4f} p_days {t['p_days']:.4f} "
            f"({len(t['day_means'])} d) ok {t['ok']}; days "
            + " ".join(f"{m:+.2f}" for m in t["day_means"]))


def summary(rows: list[dict]) -> None:
    r, rc = pooled_r([x["base_day_means"] for x in rows])
    print(f"base held-out day means: pooled lag-1 r {r:.2f} raw, {rc:.2f} Kendall-corrected "
          f"({len(rows)} windows)")
    cands = [t for x in rows for t in x["trials"]]
    r, rc = pooled_r([t["day_means"] for t in cands if len(t["day_means"]) >= 3])
    print(f"candidates' day means of the cut: pooled lag-1 r {r:.2f} raw, {rc:.2f} corrected")
    for x in rows:
        for t in x["trials"]:
            if t["cut"] >= 0.15 or t["p_pieces"] <= 0.1 or t["ok"]:
                print(trial_line(x["case"], t))
    print(f"{len(cands)} candidates; p <= 0.05: pieces "
          f"{sum(t['p_pieces'] <= 0.05 for t in cands)}, days "
          f"{sum(t['p_days'] <= 0.05 for t in cands)}; findings in "
          f"{sum(bool(x['findings']) for x in rows)} of {len(rows)} windows")


def null(out: str | None) -> None:
    from tests.generality.cases import EXTRA_WINDOWS
    from tests.generality.report import MAIN_WINDOWS

    rows = []
    for g in ("refsim", "twonode"):
        for w in (*MAIN_WINDOWS, *EXTRA_WINDOWS):
            rows.append(diagnose_case(f"{g}/{w}"))
            print(rows[-1]["case"], rows[-1]["findings"], flush=True)
    if out:
        Path(out).write_text("".join(json.dumps(x) + "\n" for x in rows))
    summary(rows)


def rho(path: str) -> None:
    """``day_p`` at several ``DAY_RHO`` for the logged candidates with a piece p <= 0.05 or
    that passed (contiguous days assumed)."""
    print(f"{'candidate (days)':56s} " + " ".join(f"rho={r:<4g}" for r in RHOS))
    for s in Path(path).read_text().splitlines():
        x = json.loads(s)
        for t in x["trials"]:
            if t["p_pieces"] <= 0.05 or t["ok"]:
                m = np.asarray(t["day_means"])
                ps = [sig.day_p(m, np.arange(len(m)), r) for r in RHOS]
                name = f"{x['case']} {t['effect']} ({len(m)})"
                print(f"{name:56s} " + " ".join(f"{p:8.3f}" for p in ps))


def short(days: int, at: float) -> None:
    """The unit tests' model-made cases at ``days`` days, change at ``at`` [d], both tests."""
    import tests.test_diagnose as td
    from gateway.diagnose import diagnose

    td.DAYS = days
    print(f"| case ({days} d, change at day {at:g}) | pieces: first finding, cut, p, start [h] "
          f"| days: first finding, cut, p, start [h] |\n| --- | --- | --- |")
    for plant in ("almeria", "prototype"):
        for effect in td.SPECS:
            cells = []
            with tempfile.TemporaryDirectory() as tmp:
                series, gh, model, t0 = td._data(Path(tmp), plant, effect, at=at)
                for on in (False, True):
                    jd.DAY_TEST = on
                    cells.append(_short_cell(diagnose(series, gh, model), effect, t0))
            print(f"| {effect}/{plant} | {cells[0]} | {cells[1]} |", flush=True)


def _p_in(reason: str) -> float:
    """The p a rejection reason states; 1 for one not judged yet (too few days, no p)."""
    return float(reason.split("p = ")[1].split(" ")[0]) if "p = " in reason else 1.0


def _short_cell(d, effect: str, t0: str) -> str:
    import tests.test_diagnose as td

    if not d.findings:
        best = min(d.rejected, key=lambda r: _p_in(r["reason"]), default=None)
        return "none" + (f" (best rejected `{best['effect']}`: {best['reason'][:60]}…)"
                         if best else "")
    f = d.findings[0]
    gain = 1.0 - d.after["free_run"]["mae"] / d.before["free_run"]["mae"]
    lag = (np.datetime64(f.start.rstrip("Z")) - np.datetime64(t0)) / np.timedelta64(1, "h")
    ok = "✓" if f.effect.name in td.EQUIVALENT[effect] else "✗"
    pv = f.evidence.split("p = ")[1].split(" ")[0] if "p = " in f.evidence else "?"
    return f"`{f.effect.name}` {ok}, {-100 * gain:.0f} %, p {pv}, {lag:+.1f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["size", "power", "null", "cases", "rho", "short"])
    ap.add_argument("args", nargs="*", help="cases: suite case labels; rho: a JSONL file")
    ap.add_argument("--test", choices=["paired_p", "day_p"], default="paired_p")
    ap.add_argument("--draws", type=int, default=4000)
    ap.add_argument("--out", help="null/cases: write the JSON lines here")
    ap.add_argument("--days", type=int, default=6, help="short: days of data (6: the tests')")
    ap.add_argument("--at", type=float, default=3.6, help="short: the change's start [d]")
    a = ap.parse_args(argv)
    if a.what == "size":
        size(a.test, a.draws)
    elif a.what == "power":
        power(min(a.draws, 1000))
    elif a.what == "null":
        null(a.out)
    elif a.what == "cases":
        rows = [diagnose_case(c) for c in a.args]
        if a.out:
            Path(a.out).write_text("".join(json.dumps(x) + "\n" for x in rows))
        for x in rows:
            for t in x["trials"]:
                print(trial_line(x["case"], t))
    elif a.what == "short":
        short(a.days, a.at)
    else:
        rho(a.args[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())

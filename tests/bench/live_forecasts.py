"""Where a ``make run``'s live forecasts lose: its estimator run again offline, by the live code.

Re-steps the run's stored minutes through the gateway's own ``GreenhousePipeline`` (the same
config, greenhouse, model and starting parameters as the run's ``gateway.toml``; only the minutes
the live estimator stepped), checks that the forecasts equal the stored live ones, and prints the
MAE of the published forecast, of its two parts (``adaptive_kf``, ``arx``) and of persistence at
each horizon, overall and by the hour of the start, with the parts' weight. Variants answer "what
if": ``--oracle`` gives the forecasts the weather the kit later measured instead of the outlook
(``--oracle-cols i_glob`` only some columns), ``--outlook`` another outlook, ``--site`` another
[site] (model and outlook), ``--params`` other starting parameters (``none``: the middle of the
box), ``--forecast`` another kind (docs/online-estimator.md, "Why make run's forecasts lose").
Targets are the readings of the store's minutes, so n can exceed the summary's by a minute or
two (minutes the live estimator had not stepped yet when the run stopped).

    .venv/bin/python -m training run --minutes 240 --out out/run | cat
    .venv/bin/python tests/bench/live_forecasts.py out/run [--oracle] [--hours]
"""

from __future__ import annotations

import argparse
import collections
import math
import sqlite3
import sys
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the package, not tests/bench/gateway.py beside this script

from gateway.estimate.outlook import Outlook  # noqa: E402
from gateway.greenhouse import Site  # noqa: E402
from gateway.model import build_model  # noqa: E402
from gateway.model.params_file import read_params  # noqa: E402
from gateway.service.config import load_config  # noqa: E402
from gateway.service.minutes import read_minutes  # noqa: E402
from gateway.service.pipeline import GreenhousePipeline, StepReport  # noqa: E402
from gateway.service.resources import prepare  # noqa: E402


class Measured:
    """The weather the kit measured over the horizon (not causal: the forecast's best case);
    columns not in ``cols`` (and minutes past the data) from ``base``."""

    name = "measured"

    def __init__(self, table: Mapping[int, Mapping[str, float]], base: Outlook,
                 cols: tuple[str, ...] | None) -> None:
        self.table, self.base, self.cols = table, base, cols

    def drivers(self, history: Mapping[str, np.ndarray], time: np.ndarray, horizon: int,
                dt: float) -> dict[str, np.ndarray]:
        now = int(np.asarray(time[-1], dtype="datetime64[s]").astype(np.int64))
        out = {c: np.array(v, float) for c, v in self.base.drivers(history, time, horizon, dt).items()}
        for c, col in out.items():
            if self.cols is not None and c not in self.cols:
                continue
            for k in range(horizon):
                v = self.table.get(now + int(dt) * (k + 1), {}).get(c, math.nan)
                col[k] = v if math.isfinite(v) else col[k]
        return out


def pipeline(run: Path, a: argparse.Namespace) -> GreenhousePipeline:
    cfg = load_config(run / "gateway.toml")
    r = prepare(cfg)[0]
    gh, model, theta0 = r.gh, r.model, r.theta0
    if a.site:
        lat, lon = (float(v) for v in a.site.split(","))
        gh = replace(gh, site=Site(lat, lon))
        model = build_model(r.settings.model, gh)
    if a.params == "none":
        theta0 = None
    elif a.params:
        theta0 = read_params(a.params, model, gh)
    est, s = cfg.estimator, r.settings
    p = GreenhousePipeline(s.name, gh, model, s.inside, s.outside, theta0,
                           horizons=est.horizons_min, outlook=a.outlook or s.outlook, seed=est.seed,
                           gap_s=est.gap_s, history_min=est.history_min,
                           forecast=a.forecast or est.forecast)
    return p


def run_again(run: Path, a: argparse.Namespace) -> list[dict]:
    """One dict per forecast: start t, horizon h [min], published f, reading y at t + h, y0 at
    t, the parts and the first part's weight."""
    p = pipeline(run, a)
    conn = sqlite3.connect(f"file:{run / 'serra.db'}?mode=ro", uri=True)
    lo, hi = conn.execute("SELECT min(minute), max(minute) + 60 FROM minute WHERE device_id=?",
                          (p.inside,)).fetchone()
    minutes = read_minutes(conn, p.inside, p.outside, lo, hi)
    table = {m.minute: m.values for m in minutes}
    stepped = {int(t) for (t,) in conn.execute(
        "SELECT t FROM estimates WHERE greenhouse=? AND name='t_in_next'", (p.name,))}
    live = {(int(t), n): v for t, n, v in conn.execute(
        "SELECT t, name, value FROM estimates WHERE greenhouse=? AND source='forecast'", (p.name,))}
    conn.close()
    if a.oracle or a.oracle_cols:
        p.outlook = Measured(table, p.outlook, tuple(a.oracle_cols.split(",")) if a.oracle_cols else None)
    parts: dict[tuple[int, int], dict[str, float]] = {}
    now = [0]
    comb = p.forecaster.comb
    if comb is not None:
        add = comb.add

        def spy(made: Mapping[int, Mapping[str, float]] | None) -> None:
            for h, d in (made or {}).items():
                parts[(now[0], h)] = {**d, "w": comb.weights(h)[comb.names[0]]}
            add(made)
        comb.add = spy  # type: ignore[method-assign]
    out, report = [], StepReport()
    for m in minutes:
        if m.minute in stepped:
            now[0] = m.minute
            out += [(int(r.t), int(r.name[5:-3]), r.value) for r in p._advance_to(m, report)
                    if r.source == "forecast"]
    diff = [abs(v - live.get((t, f"t_in+{h}min"), math.nan)) for t, h, v in out]
    print(f"{len(out)} forecasts re-made ({len(live)} stored live); largest difference from the "
          f"live ones {np.nanmax(diff) if diff else math.nan:.3g} K")
    t_in = {t: v["t_in"] for t, v in table.items()}
    return [{"t": t, "h": h, "f": f, "y": t_in.get(t + 60 * h, math.nan), "y0": t_in.get(t, math.nan),
             **parts.get((t, h), {})} for t, h, f in out]


def mae(rows: list[dict], key: str) -> float:
    e = [abs(r[key] - r["y"]) for r in rows if math.isfinite(r.get(key, math.nan))]
    return float(np.mean(e)) if e else math.nan


def table(rows: list[dict], hours: bool) -> None:
    by = collections.defaultdict(list)
    for r in rows:
        if math.isfinite(r["y"]) and math.isfinite(r["y0"]):
            by[r["h"]].append(r)
    print("| h [min] | start | n | published | persistence | adaptive_kf | arx | weight of adaptive_kf |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for h in sorted(by):
        groups = [("all", by[h])]
        if hours:
            per = collections.defaultdict(list)
            for r in by[h]:
                per[r["t"] // 3600 % 24].append(r)
            groups += [(f"{k:02d} h", v) for k, v in sorted(per.items())]
        for name, g in groups:
            w = np.nanmean([r.get("w", math.nan) for r in g]) if any("w" in r for r in g) else math.nan
            print(f"| {h} | {name} | {len(g)} | {mae(g, 'f'):.3f} | {mae(g, 'y0'):.3f} | "
                  f"{mae(g, 'adaptive_kf'):.3f} | {mae(g, 'arx'):.3f} | {w:.2f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="the run's folder (gateway.toml, serra.db)")
    ap.add_argument("--oracle", action="store_true", help="the weather later measured")
    ap.add_argument("--oracle-cols", metavar="A,B", help="only these columns measured")
    ap.add_argument("--outlook", help="another outlook (hold-latest, clear-sky-trend)")
    ap.add_argument("--site", metavar="LAT,LON", help="another [site]")
    ap.add_argument("--params", help="other starting parameters (a params TOML, or none)")
    ap.add_argument("--forecast", help="another forecast kind (adaptive, adaptive_kf, combined)")
    ap.add_argument("--hours", action="store_true", help="also by the hour of the start")
    a = ap.parse_args(argv)
    table(run_again(a.run, a), a.hours)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

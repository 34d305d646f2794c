"""Which daily weather explains the base's day-by-day error? (issue 10; docs/effects.md, "The
base's day-scale error against daily weather")

For every effect-free window of the dev generators (refsim, twonode; the suite's 10 windows
each, seed 1 as the suite), the base is calibrated as the diagnosis calibrates it
(search.prepare: the first half, structure chosen on the inner split), and the daily means of
its free-run residual (measured − model [K]) are taken on the held-out half (the diagnosis's
half-day blocks) and, reported apart, on the calibration half (judge.calibration_free_run, day
blocks). Daily weather features are computed from the kit columns only (and the clear sky from
the site, as the model does). Each feature set is scored by the leave-one-window-out R² of the
held-out daily means, pooled over the windows (ordinary least squares with an intercept).
Never the held-out generator.

    python tests/generality/day_residual.py [--generators refsim,twonode] [--seed 1]
        [--from-json out/dr/day_residual.json] [--out out/dr]
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

from gateway.model.psychrometrics import vapour_pressure_deficit  # noqa: E402
from tests.generality.base_carry import NIGHT_W_M2, per_day  # noqa: E402
from tests.generality.cases import EXTRA_WINDOWS, Case, case_series  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402
from tests.generality.report import MAIN_WINDOWS  # noqa: E402

DEV = ("refsim", "twonode")
DAY_S = 86400.0

FEATURE_SETS: dict[str, tuple[str, ...]] = {
    # single features first, then physically named sets
    "radiation": ("rad",),
    "clear-sky index": ("kt",),
    "wind": ("wind",),
    "night wind": ("wind_night",),
    "T_out mean": ("t_out",),
    "T_out change": ("dt_out",),
    "previous day's radiation": ("rad_prev",),
    "VPD out": ("vpd_out",),
    "VPD in": ("vpd_in",),
    "night clearness": ("night_clear",),
    "latent (radiation x VPD in)": ("rad", "rad_vpd_in"),
    "slow store (radiation, previous days')": ("rad", "rad_prev", "rad_prev3"),
    "calm (wind, night wind)": ("wind", "wind_night"),
    "night sky (clearness, night wind)": ("night_clear", "wind_night"),
    "regime (T_out mean, change)": ("t_out", "dt_out"),
    "radiation + T_out change": ("rad", "dt_out"),
    "shift: T_out": ("t_out_shift",),
    "shift: radiation": ("rad_shift",),
    "shift: wind": ("wind_shift",),
    "shift: VPD in": ("vpd_in_shift",),
    "shift: T_out, radiation": ("t_out_shift", "rad_shift"),
    "shift: T_out, radiation, wind, VPD in": ("t_out_shift", "rad_shift", "wind_shift",
                                              "vpd_in_shift"),
    "all": ("rad", "kt", "wind", "wind_night", "t_out", "dt_out", "rad_prev", "rad_prev3",
            "vpd_out", "vpd_in", "rad_vpd_in", "night_clear"),
}
"""Each set is a list of columns of :func:`daily_features`; every set is reported. ``<name>_shift``
is the column minus its mean over the window's calibration days (how far the day lies from the
weather the base was calibrated on: a base whose parameters absorb a missing term errs when
the weather moves away from its calibration)."""


def daily_features(x: dict[str, np.ndarray], clear: np.ndarray, dt: float) -> dict[str, np.ndarray]:
    """Per day since the first row (rows on a grid of ``dt`` [s]): kit-column weather features.

    rad: mean global radiation [W m-2]; kt: its sum over the clear sky's sum ``clear`` [-];
    wind, wind_night: mean wind, all day / where i_glob < NIGHT_W_M2 [m s-1]; t_out: mean
    [°C]; dt_out: its change since the day before [K] (0 on day 0); rad_prev, rad_prev3: the
    previous day's radiation and the mean of the previous three (the first day's own where
    there are none) [W m-2]; vpd_out, vpd_in [kPa]; rad_vpd_in: the daily mean of i_glob × the
    inside VPD [W m-2 kPa] (transpiration's drive: radiation and the inside deficit);
    night_clear: 1 − the kit's carried cloud fraction at night [-]."""
    n = len(x["t_out"])
    day = (np.arange(n) * dt // DAY_S).astype(int)
    days = np.unique(day)
    night = x["i_glob"] < NIGHT_W_M2
    vpd_in = vapour_pressure_deficit(x["t_in"], x["rh_in"])
    rows: dict[str, list[float]] = {k: [] for k in (
        "rad", "kt", "wind", "wind_night", "t_out", "vpd_out", "vpd_in", "rad_vpd_in",
        "night_clear")}
    for d in days:
        m = day == d
        mn = m & night
        rows["rad"].append(float(np.nanmean(x["i_glob"][m])))
        rows["kt"].append(float(np.nansum(x["i_glob"][m]) / max(np.nansum(clear[m]), 1e-9)))
        rows["wind"].append(float(np.nanmean(x["wind"][m])))
        rows["wind_night"].append(float(np.nanmean(x["wind"][mn])) if mn.any() else np.nan)
        rows["t_out"].append(float(np.nanmean(x["t_out"][m])))
        rows["vpd_out"].append(float(np.nanmean(vapour_pressure_deficit(x["t_out"][m], x["rh_out"][m]))))
        rows["vpd_in"].append(float(np.nanmean(vpd_in[m])))
        rows["rad_vpd_in"].append(float(np.nanmean(x["i_glob"][m] * vpd_in[m])))
        rows["night_clear"].append(float(1.0 - np.nanmean(x["cloud"][mn])) if mn.any() else np.nan)
    out = {k: np.array(v) for k, v in rows.items()}
    t = out["t_out"]
    out["dt_out"] = np.concatenate([[0.0], np.diff(t)])
    r = out["rad"]
    out["rad_prev"] = np.concatenate([[r[0]], r[:-1]])
    out["rad_prev3"] = np.array([np.mean(r[max(i - 3, 0):i]) if i else r[0] for i in range(len(r))])
    return out


def daily_means(r: np.ndarray, first_row: int, dt: float, n_days: int) -> np.ndarray:
    """Mean of ``r`` (rows ``first_row`` onwards on a grid of ``dt`` [s]) per day 0..n_days-1;
    NaN for a day without finite rows."""
    means = per_day(r, first_row, dt)
    return np.array([means.get(d, np.nan) for d in range(n_days)])


def lowo_r2(y: np.ndarray, feats: np.ndarray, groups: np.ndarray) -> float:
    """Leave-one-group-out R² of an OLS fit with intercept: each group's ``y`` predicted from a
    fit on the other groups; 1 − SSE / the total sum of squares about the pooled mean. Rows
    with a NaN are dropped. Can be negative (worse than the mean)."""
    ok = np.isfinite(y) & np.all(np.isfinite(feats), axis=1)
    y, feats, groups = y[ok], feats[ok], groups[ok]
    pred = np.full(len(y), np.nan)
    if len(np.unique(groups)) < 2:
        return float("nan")
    for g in np.unique(groups):
        tr = groups != g
        a = np.column_stack([np.ones(tr.sum()), feats[tr]])
        coef, *_ = np.linalg.lstsq(a, y[tr], rcond=None)
        pred[~tr] = np.column_stack([np.ones((~tr).sum()), feats[~tr]]) @ coef
    sst = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - pred) ** 2)) / sst if sst > 0 else float("nan")


def window_days(generator: str, window: str, seed: int) -> dict:
    """One window: the base's daily residual means (calibration and held-out) and features."""
    from gateway.diagnose import judge as jd
    from gateway.diagnose.search import prepare
    from gateway.model import solar
    from gateway.model.drivers import site_of

    if generator in HELD_OUT:
        raise SystemExit(f"{generator} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = case_series(Case("diagnose", generator, window, "none", seed),
                                           Path(tmp))
    start = prepare(series, gh, model)
    st = start.state
    x, dt, s = st.ctx.x, st.ctx.dt, st.ctx.split
    n_days = int(round(len(x["t_in"]) * dt / DAY_S))
    r_h = x["t_in"][s:] - st.current_pred["free_run"]
    r_c = jd.calibration_free_run(st.model0, start.theta, x, gh, dt, s)
    lat, lon = site_of(gh) or (0.0, 0.0)  # the suite's houses all have a [site]
    clear = solar.clear_sky_global(solar.solar_position(start.coarse.time, lat, lon).cos_zenith)
    held = daily_means(r_h, s, dt, n_days)
    cal = daily_means(r_c, 0, dt, n_days)
    feats = daily_features(x, clear, dt)
    return {"generator": generator, "window": window, "split_day": s * dt / DAY_S,
            "heldout": held.tolist(), "calibration": cal.tolist(),
            "heldout_mae": float(np.nanmean(np.abs(r_h))),
            "features": {k: v.tolist() for k, v in feats.items()}}


def column(rec: dict, name: str) -> np.ndarray:
    """A feature column of one window's record; ``<name>_shift`` relative to its calibration
    days' mean (days before ``split_day``)."""
    if name.endswith("_shift"):
        v = np.asarray(rec["features"][name[:-len("_shift")]], float)
        cal = np.arange(len(v)) < int(round(rec["split_day"]))
        return v - np.nanmean(v[cal])
    return np.asarray(rec["features"][name], float)


def stack(records: list[dict], part: str, names: tuple[str, ...]
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(y, features, group) over all windows' days of ``part`` (``heldout``/``calibration``)."""
    ys, fs, gs = [], [], []
    for i, rec in enumerate(records):
        y = np.asarray(rec[part], float)
        ys.append(y)
        fs.append(np.column_stack([column(rec, k)[:len(y)] for k in names]))
        gs.append(np.full(len(y), i))
    return np.concatenate(ys), np.vstack(fs), np.concatenate(gs)


def score(records: list[dict]) -> list[dict]:
    """Every feature set's leave-one-window-out R²: held-out days pooled over all windows, per
    generator, and (apart) the calibration days pooled."""
    rows = []
    gens = sorted({r["generator"] for r in records})
    for label, names in FEATURE_SETS.items():
        row: dict = {"set": label, "features": list(names)}
        for part in ("heldout", "calibration"):
            y, f, g = stack(records, part, names)
            row[f"r2_{part}"] = lowo_r2(y, f, g)
        for gen in gens:
            sub = [r for r in records if r["generator"] == gen]
            y, f, g = stack(sub, "heldout", names)
            row[f"r2_heldout_{gen}"] = lowo_r2(y, f, g)
        rows.append(row)
    return rows


def correlations(records: list[dict], part: str = "heldout") -> dict[str, float]:
    """Pooled Pearson r of each feature with the daily residual mean (its sign: the direction)."""
    names = tuple(records[0]["features"])
    y, f, _ = stack(records, part, names)
    out = {}
    for j, k in enumerate(names):
        ok = np.isfinite(y) & np.isfinite(f[:, j])
        out[k] = float(np.corrcoef(y[ok], f[ok, j])[0, 1]) if ok.sum() > 2 else float("nan")
    return out


def same_weather(records: list[dict]) -> str:
    """Do two generators err on the same days? Pearson r of their held-out daily means over the
    windows both ran, and the SD of the calibration and held-out daily means."""
    by = {(r["generator"], r["window"]): np.asarray(r["heldout"], float) for r in records}
    gens = sorted({g for g, _ in by})
    cal = np.concatenate([np.asarray(r["calibration"], float) for r in records])
    held = np.concatenate([np.asarray(r["heldout"], float) for r in records])
    text = (f"SD of the daily means: calibration days {np.nanstd(cal):.3f} K, held-out days "
            f"{np.nanstd(held):.3f} K.")
    if len(gens) == 2:
        a, b = [], []
        for (g, w), v in by.items():
            if g == gens[0] and (gens[1], w) in by:
                a.append(v)
                b.append(by[(gens[1], w)])
        x, y = np.concatenate(a), np.concatenate(b)
        ok = np.isfinite(x) & np.isfinite(y)
        text += (f" {gens[0]} vs {gens[1]} on the same window and day: r "
                 f"{np.corrcoef(x[ok], y[ok])[0, 1]:+.2f} over {int(ok.sum())} days.")
    return text


def markdown(records: list[dict], rows: list[dict], command: str) -> str:
    gens = sorted({r["generator"] for r in records})
    y, _, _ = stack(records, "heldout", ("rad",))
    lines = [f"`{command}`", "",
             f"{len(records)} windows, {int(np.isfinite(y).sum())} held-out days; held-out daily "
             f"means: mean {np.nanmean(y):+.3f} K, sd {np.nanstd(y):.3f} K, mean |.| "
             f"{np.nanmean(np.abs(y)):.3f} K.", "",
             "| feature set | LOWO R² held-out (pooled) | " + " | ".join(gens)
             + " | LOWO R² calibration (pooled) |",
             "|---|---|" + "---|" * len(gens) + "---|"]
    for r in rows:
        lines.append(f"| {r['set']} | {r['r2_heldout']:+.3f} | "
                     + " | ".join(f"{r[f'r2_heldout_{g}']:+.3f}" for g in gens)
                     + f" | {r['r2_calibration']:+.3f} |")
    lines += ["", same_weather(records)]
    lines += ["", "Pooled Pearson r of each feature with the held-out daily mean: "
              + ", ".join(f"{k} {v:+.2f}" for k, v in correlations(records).items()) + "."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--generators", default=",".join(DEV), help="dev generators (refsim,twonode)")
    ap.add_argument("--windows", default=None,
                    help="comma-separated windows (default: the suite's 10 effect-free ones)")
    ap.add_argument("--seed", type=int, default=1, help="the generators' sensor seed (1, the suite's)")
    ap.add_argument("--from-json", default=None, help="rescore the windows of an earlier run")
    ap.add_argument("--out", default="out/dr", help="directory for day_residual.json/.md")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.from_json:
        records = json.loads(Path(a.from_json).read_text())["windows"]
    else:
        windows = a.windows.split(",") if a.windows else [*MAIN_WINDOWS, *EXTRA_WINDOWS]
        records = []
        for g in a.generators.split(","):
            for w in windows:
                t0 = time.perf_counter()
                records.append(window_days(g, w, a.seed))
                print(f"{g}/{w}: held-out MAE {records[-1]['heldout_mae']:.3f} K "
                      f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
    rows = score(records)
    command = "python tests/generality/day_residual.py " + " ".join(argv or sys.argv[1:])
    (out / "day_residual.json").write_text(json.dumps({"windows": records, "scores": rows},
                                                      indent=1))
    (out / "day_residual.md").write_text(markdown(records, rows, command.strip()))
    print(markdown(records, rows, command.strip()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

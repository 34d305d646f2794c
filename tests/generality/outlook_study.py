"""Study: what a causal weather outlook could still gain for the forecasts of T_in (issue 10).

Three parts, none of which reruns the estimator (an outlook only changes the driver blocks
replay forecasts with, recomputed here from each kept replay's drivers):

A. The weather alone, on the Bleiswijk stretch 2009-11-04..24 (outside the generality windows,
   where ``clear-sky-trend`` was tuned), kit sensor noise added: the 30-min radiation and the
   60-min mean radiation errors of ``clear-sky-trend`` and of its causal variants
   (tests/generality/outlook_variants.py), and the in-sample least-squares ceiling of the
   60-min mean from six trailing clear-sky indices (15 min … 3 days).
B. ``corrected_outlook`` (what the gateway publishes) on the kept tuning replays (refsim,
   twonode) with: the current outlook; each driver replaced by the measured future and a
   perfect hourly cloudiness (not causal: what a weather forecast would be worth); the causal
   radiation variants.
C. The error correction with extra features: a second daily harmonic, the last matured error
   of the measured-weather forecast, the hold-latest forecast stacked (these two for the
   outlook only).

``--held-out`` scores the held-out generator's replays instead (part B's causal rows and C),
once, after the choice; part A is the weather only.

    nice -n 5 .venv/bin/python tests/generality/outlook_study.py out/fc       # ~4 min
    nice -n 5 .venv/bin/python tests/generality/outlook_study.py out/fc --held-out
"""

from __future__ import annotations

import argparse
import pickle
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.estimate import correction  # noqa: E402
from gateway.estimate import replay as rp  # noqa: E402
from gateway.estimate.clear_sky_trend import ClearSkyTrend, _unix  # noqa: E402
from gateway.estimate.horizon import outlook_drivers  # noqa: E402
from gateway.estimate.outlook import HoldLatest  # noqa: E402
from gateway.greenhouse import Site  # noqa: E402
from gateway.kitcsv import COLUMNS  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402
from tests.generality.kit_sensors import kit_columns  # noqa: E402
from tests.generality.outlook_variants import (  # noqa: E402
    HourlyCloudiness,
    IndexBlend,
    Measured,
    OnlineBlend,
    correct_with,
)
from tests.generality.windows import bleiswijk_window  # noqa: E402

TUNING_STRETCH = ("2009-11-04T00:00", 20.0)
"""Start (UTC) and days of the Bleiswijk stretch outside the generality windows."""
RADIATION_VARIANTS: dict[str, Callable[[Site], ClearSkyTrend]] = {
    "clear-sky-trend (now)": ClearSkyTrend,
    "blend to the 1-d index, tau 60 min": lambda s: IndexBlend(s, 86400.0, 3600.0),
    "blend to the 3-d index, tau 60 min": lambda s: IndexBlend(s, 3 * 86400.0, 3600.0),
    "blend to the 3-d index, online weight": OnlineBlend,
}
"""The causal radiation outlooks compared (part A and B)."""
ORACLES = {"measured i_glob": ("i_glob",), "measured t_out": ("t_out",),
           "measured rh_out and wind": ("rh_out", "wind"),
           "measured weather (all four)": ("i_glob", "t_out", "rh_out", "wind")}
BEST_CAUSAL = "blend to the 1-d index, tau 60 min, + second daily harmonic"
"""The small causal gains together (part B's blend and part C's harmonic)."""
PERFECT_HOURLY = "perfect hourly cloudiness (not causal)"


# -- A: the weather alone ------------------------------------------------------------------
def _kit_weather(seed: int = 1) -> tuple[np.ndarray, dict[str, np.ndarray], Site]:
    w = bleiswijk_window(*TUNING_STRETCH)
    cols = kit_columns(w.t_out, 1000.0 * w.vapour_pressure, w, seed)
    return w.time[:: 5], cols, Site(w.latitude, w.longitude)


def part_a() -> str:
    time, cols, site = _kit_weather()
    dt, horizon = 300.0, 12
    ig = cols["i_glob"]
    starts = np.arange(3 * 288, len(time) - horizon)  # after three days of history
    truth = ig[starts[:, None] + np.arange(1, horizon + 1)[None, :]]
    lines = ["| radiation outlook | 30 min MAE / RMSE [W m-2] | 60-min mean MAE / RMSE |",
             "| --- | --- | --- |"]
    day = None
    for label, make in RADIATION_VARIANTS.items():
        f = make(site).drivers_at({"i_glob": ig}, time, starts, horizon, dt)["i_glob"]
        if day is None:
            day = truth.mean(1) + f.mean(1) > 10.0  # starts with daylight in the hour
        e30, e60 = (f[:, 5] - truth[:, 5])[day], (f.mean(1) - truth.mean(1))[day]
        lines.append(f"| {label} | {np.abs(e30).mean():.1f} / {np.sqrt(np.mean(e30 ** 2)):.1f} | "
                     f"{np.abs(e60).mean():.1f} / {np.sqrt(np.mean(e60 ** 2)):.1f} |")
    lines.append(f"| least-squares ceiling, six trailing indices (in-sample) | | "
                 f"{_ceiling(ig, time, site, starts, truth, day)} |")
    return "\n".join(lines) + "\n"


def _ceiling(ig, time, site, starts, truth, day) -> str:
    """60-min mean radiation fitted in-sample on the clear sky ahead × six trailing indices."""
    unix = _unix(time)
    ahead = unix[starts][:, None] + np.arange(1, truth.shape[1] + 1)[None, :] * 300.0
    clear = ClearSkyTrend(site)._clear(ahead.ravel()).reshape(ahead.shape).mean(1)
    cols = [ClearSkyTrend(site, index_window=w).clear_sky_index(ig, unix, 300.0)[starts]
            for w in (900.0, 1800.0, 3600.0)]
    cols += [IndexBlend(site, w).reference_index(ig, unix, 300.0)[starts]
             for w in (3 * 3600.0, 86400.0, 3 * 86400.0)]
    x = np.column_stack([np.column_stack(cols) * clear[:, None], clear])[day]
    y = truth.mean(1)[day]
    e = x @ np.linalg.lstsq(x, y, rcond=None)[0] - y
    return f"{np.abs(e).mean():.1f} / {np.sqrt(np.mean(e ** 2)):.1f}"


# -- B and C: T_in ----------------------------------------------------------------------------
def _score(res, outlook) -> dict[str, dict[str, float]]:
    """Horizon → forecast → MAE of the kept replay ``res`` forecast with ``outlook``."""
    reach = rp.steps_of(rp.HORIZONS, res.dt)
    kit = [c for c in COLUMNS if c in res.x]
    n = len(res.time)
    res.ahead = outlook_drivers(outlook, res.x, kit, res.time, res.dt, res.gh,
                                np.arange(max(n - 1, 0)), max(reach.values()))
    rp.score_forecasts(res, reach)
    return _mae(res)


def _mae(res) -> dict[str, dict[str, float]]:
    rep = rp.report(res, warmup=int(round(86400.0 / res.dt)))["horizons"]
    return {h: {k: m["mae"] for k, m in per.items()} for h, per in rep.items()}


def _on_grid(res, minutes: int, key: str) -> np.ndarray:
    f = res.horizons[minutes]
    out = np.full(len(res.measured), np.nan)
    out[f["target"] - int(round(minutes * 60.0 / res.dt))] = f[key]
    return out


def _extra_features(res, hold: dict[int, np.ndarray]) -> dict[str, tuple[dict[int, np.ndarray], bool]]:
    """Part C's extra columns per horizon (in model steps), values at each start, all known
    at the start, and whether they also go into the measured-weather correction: sin/cos 2ωτ;
    the error of the measured-weather ``combined`` made h earlier, whose target is the reading
    now; the hold-latest ``combined`` minus this outlook's. (The reading's level and its
    departure from the last day's mean, studied here first, are in the correction itself since
    2026-11-26.)"""
    n, w = len(res.measured), 4.0 * np.pi * correction.hour_of_day(res.time) / 24.0
    out: dict[str, tuple[dict[int, np.ndarray], bool]] = {}
    for minutes in res.horizons:
        steps = int(round(minutes * 60.0 / res.dt))
        last = np.full(n, np.nan)
        last[steps:] = res.measured[steps:] - _on_grid(res, minutes, "combined")[:-steps]
        stacked = hold[minutes] - _on_grid(res, minutes, "combined_outlook")
        for label, cols, both in (
                ("second daily harmonic", [np.sin(w), np.cos(w)], True),
                ("last measured-weather error", [last], False),
                ("hold-latest stacked", [stacked], False)):
            out.setdefault(label, ({}, both))[0][steps] = np.column_stack(cols)
    return out


def _outlooks(site: Site, held_out: bool) -> dict[str, object]:
    """Part B's outlooks by label (the non-causal ones on the tuning replays only)."""
    out: dict[str, object] = {label: make(site) for label, make in RADIATION_VARIANTS.items()}
    if not held_out:
        for label, cols in ORACLES.items():
            out[f"{label} (not causal)"] = Measured(ClearSkyTrend(site), cols)
        out[PERFECT_HOURLY] = HourlyCloudiness(site)
    return out


def _case(res, held_out: bool) -> dict[str, dict]:
    """Variant → horizon → forecast → MAE for one kept replay."""
    site = res.gh.site
    got = {label: _score(res, outlook) for label, outlook in _outlooks(site, held_out).items()}
    _score(res, HoldLatest())
    hold = {m: _on_grid(res, m, "combined_outlook") for m in res.horizons}
    _score(res, ClearSkyTrend(site))
    extras = _extra_features(res, hold)
    for label, (extra, both) in extras.items():
        correct_with(res, extra, "_outlook")
        correct_with(res, extra if both else {}, "")
        got[f"correction + {label}"] = _mae(res)
    _score(res, IndexBlend(site, 86400.0, 3600.0))  # the small causal gains together
    correct_with(res, extras["second daily harmonic"][0], "_outlook")
    got[BEST_CAUSAL] = _mae(res)
    return got


def study(folder: Path, held_out: bool) -> dict[str, dict[str, dict[str, dict[str, float]]]]:
    """Variant → case → horizon → forecast → MAE, over the tuning (or held-out) replays."""
    table: dict[str, dict] = {}
    for f in sorted(folder.glob("*.pkl")):
        if (f.stem.split("-", 1)[0] in HELD_OUT) != held_out:
            continue
        for label, per in _case(pickle.loads(f.read_bytes()), held_out).items():
            table.setdefault(label, {})[f.stem] = per
        print(f"  {f.stem} done", file=sys.stderr, flush=True)
    return table


def markdown(table: dict) -> str:
    """corrected_outlook at 15/30/60 min per case, the mean ratio to the current outlook's,
    and the windows meeting the outlook goal (≤ 0.8 × persistence at 30 and 60 min)."""
    now = table["clear-sky-trend (now)"]
    cases = list(now)
    head = " | ".join(f"{c} 15 / 30 / 60" for c in cases)
    lines = [f"| variant | {head} | / now | outlook goal |", "|" + " --- |" * (len(cases) + 3)]
    bound = " | ".join(" / ".join(f"{0.8 * now[c][h]['persistence']:.3f}" if h != "15" else "-"
                                  for h in ("15", "30", "60")) for c in cases)
    lines.append(f"| goal: ≤ 0.8 × persistence | {bound} | | |")
    for label, per in table.items():
        cells, ratios, goal = [], [], 0
        for c in cases:
            m = {h: per[c][h]["corrected_outlook"] for h in ("15", "30", "60")}
            cells.append(" / ".join(f"{m[h]:.3f}" for h in ("15", "30", "60")))
            ratios += [m[h] / now[c][h]["corrected_outlook"] for h in m]
            goal += all(m[h] <= 0.8 * per[c][h]["persistence"] for h in ("30", "60"))
        spread = f"{np.mean(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {spread} | {goal} / {len(cases)} |")
    return "\n".join(lines) + "\n"


def measured_markdown(table: dict) -> str:
    """Part C with the measured weather: ``corrected`` at 15/30/60 min per case for the
    correction features that also go into the measured-weather correction, the mean ratio to
    the current one and the windows meeting the measured-weather goal (≤ 0.7 × persistence and
    below the ARX at every horizon)."""
    now = table["clear-sky-trend (now)"]
    cases = list(now)
    lines = ["| correction | " + " | ".join(f"{c} 15 / 30 / 60" for c in cases)
             + " | / now | measured goal |", "|" + " --- |" * (len(cases) + 3)]
    for label in ("clear-sky-trend (now)", "correction + second daily harmonic"):
        per, cells, ratios, goal = table[label], [], [], 0
        for c in cases:
            hs = per[c]
            cells.append(" / ".join(f"{hs[h]['corrected']:.3f}" for h in ("15", "30", "60")))
            ratios += [hs[h]["corrected"] / now[c][h]["corrected"] for h in hs]
            goal += all(m["corrected"] <= 0.7 * m["persistence"] and m["corrected"] < m["arx"]
                        for m in hs.values())
        spread = f"{np.mean(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})"
        name = "now" if label.startswith("clear") else label.removeprefix("correction + ")
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {spread} | {goal} / {len(cases)} |")
    return "\n".join(lines) + "\n"


def side_by_side(table: dict) -> str:
    """Per case and horizon: persistence, the ARX (measured weather and outlook), ``corrected``
    with the outlook now, with the best causal variant and with a perfect hourly cloudiness."""
    now, best = table["clear-sky-trend (now)"], table[BEST_CAUSAL]
    hourly = table.get(PERFECT_HOURLY, {})
    lines = ["| case | h [min] | persistence | ARX | ARX, outlook | corrected, outlook: now | "
             "best causal variant | perfect hourly cloudiness (not causal) | goal ≤ |",
             "|" + " --- |" * 9]
    for c, per in now.items():
        for h, m in per.items():
            cloud = f"{hourly[c][h]['corrected_outlook']:.3f}" if c in hourly else "-"
            goal = f"{0.8 * m['persistence']:.3f}" if h != "15" else "-"
            lines.append(f"| {c} | {h} | {m['persistence']:.3f} | {m['arx']:.3f} | "
                         f"{m['arx_outlook']:.3f} | {m['corrected_outlook']:.3f} | "
                         f"{best[c][h]['corrected_outlook']:.3f} | {cloud} | {goal} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kept", help="the directory of tests/generality/forecasts.py --keep")
    ap.add_argument("--held-out", action="store_true", help="score the held-out generator only")
    a = ap.parse_args(argv)
    print("A. radiation on the Bleiswijk stretch "
          f"{TUNING_STRETCH[0][:10]} + {TUNING_STRETCH[1]:.0f} d, starts with daylight\n")
    print(part_a())
    which = "held-out" if a.held_out else "tuning"
    print(f"B/C. corrected_outlook MAE [K] on the {which} replays\n")
    table = study(Path(a.kept), a.held_out)
    print(markdown(table))
    print(side_by_side(table))
    print("C, measured weather: corrected MAE [K]\n")
    print(measured_markdown(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

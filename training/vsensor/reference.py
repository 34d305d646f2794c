"""The training target under the microscope: the explicit (vent-based) flow against the truth.

``python -m training.vsensor reference --data FILE...`` replays a kit CSV with the vent signal
(scenario a, gateway/vsensor/adaptive.py), keeps the parameters the online estimator holds at
every minute, and reports for the explicit flow G (III.31):

- its level and spread beside the simulator's true flow (``g_vent + g_leak`` of
  ``<stem>.truth.npz``, when the file comes from the simulator);
- its peaks (minutes above ``above`` m3 s-1): the truth there, the wind, |T_in − T_out|, the
  vent openings, the estimator's vent coefficients c_ven_d and c_ven_w beside their medians,
  and the hours they fall in;
- the 99th percentile of G where |ΔT| < 0.5 K (the heat loss barely constrains G there) and
  elsewhere.

This is what docs/vsensor.md ("The reference flow's peaks") is built from.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.vsensor.adaptive import Overrides, run_adaptive
from training.vsensor.dataset import WARMUP_STEPS, load_checked

LOW_DT_K = 0.5


@dataclass
class Peaks:
    minutes: int
    hours: list[str]  # UTC hours holding a peak minute
    truth_mean: float | None  # true flow at the peak minutes [m3 s-1]
    truth_min: float | None
    wind: float  # mean at the peaks [m s-1]
    abs_dt: float  # mean |T_in - T_out| at the peaks [K]
    vent_roof: float  # mean opening at the peaks [%]
    vent_side: float
    c_ven_d: float  # median at the peaks [-]
    c_ven_w: float


@dataclass
class ReferenceStudy:
    source: str
    minutes: int  # scored (first hour left out)
    explicit: dict[str, float]  # mean, p99, max [m3 s-1]
    truth: dict[str, float] | None  # the same for the simulator's true flow
    r_truth: float | None  # Pearson r explicit vs truth
    mae_truth: float | None  # [m3 s-1]
    file_wind: float  # means over the file
    file_abs_dt: float
    c_ven_d_median: float
    c_ven_w_median: float
    p99_low_dt: float | None  # G's 99th percentile where |ΔT| < LOW_DT_K, and elsewhere
    p99_other_dt: float | None
    above: float
    peaks: Peaks


def _stats(v: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(v)), "p99": float(np.percentile(v, 99)), "max": float(np.max(v))}


def true_flow(csv: str | Path, n: int) -> np.ndarray | None:
    """The simulator's true flow ``g_vent + g_leak`` [m3 s-1] beside ``csv``, if any."""
    npz = Path(csv).with_suffix("").with_name(Path(csv).stem + ".truth.npz")
    if not npz.exists():
        return None
    with np.load(npz) as d:
        if "g_vent" not in d.files or len(d["g_vent"]) != n:
            return None
        return (d["g_vent"] + d["g_leak"]).astype(float)


def study(path: str | Path, gh: Greenhouse, kind: str = "almeria", overrides: Overrides | None = None,
          seed: int = 0, above: float = 30.0,
          progress: Callable[[int], None] | None = None) -> ReferenceStudy:
    """Replay ``path`` with the vent signal and describe its explicit flow (see module doc).
    ``progress(rows)`` during the replay (as ``run_adaptive``'s)."""
    series = load_checked(path, gh, kind)
    run = run_adaptive(kind, series, gh, vents=True, overrides=overrides, seed=seed,
                       progress=progress)
    keep = np.arange(len(series)) >= WARMUP_STEPS
    keep &= np.isfinite(run.flow)
    g = run.flow[keep]
    p = {n: run.theta[keep, j] for j, n in enumerate(run.names)}
    x = {k: np.asarray(run.x[k], float)[keep] for k in ("t_in", "t_out", "wind")}
    vents = {k: np.asarray(series[k], float)[keep] if k in series else np.zeros(g.size)
             for k in ("vent_roof", "vent_side")}
    abs_dt = np.abs(x["t_in"] - x["t_out"])
    truth = true_flow(path, len(series))
    gt = None if truth is None else truth[keep]
    pk = g > above
    hours = np.unique(series.time[keep][pk].astype("datetime64[h]"))

    def _mean(v, m):
        return float(np.mean(v[m])) if m.any() else float("nan")

    low = abs_dt < LOW_DT_K
    peaks = Peaks(
        minutes=int(pk.sum()), hours=[f"{h}Z" for h in hours],
        truth_mean=None if gt is None or not pk.any() else float(gt[pk].mean()),
        truth_min=None if gt is None or not pk.any() else float(gt[pk].min()),
        wind=_mean(x["wind"], pk), abs_dt=_mean(abs_dt, pk), vent_roof=_mean(vents["vent_roof"], pk),
        vent_side=_mean(vents["vent_side"], pk),
        c_ven_d=float(np.median(p["c_ven_d"][pk])) if pk.any() else float("nan"),
        c_ven_w=float(np.median(p["c_ven_w"][pk])) if pk.any() else float("nan"),
    )
    return ReferenceStudy(
        source=str(path), minutes=int(keep.sum()), explicit=_stats(g),
        truth=None if gt is None else _stats(gt),
        r_truth=None if gt is None else float(np.corrcoef(g, gt)[0, 1]),
        mae_truth=None if gt is None else float(np.mean(np.abs(g - gt))),
        file_wind=float(x["wind"].mean()), file_abs_dt=float(abs_dt.mean()),
        c_ven_d_median=float(np.median(p["c_ven_d"])), c_ven_w_median=float(np.median(p["c_ven_w"])),
        p99_low_dt=float(np.percentile(g[low], 99)) if low.any() else None,
        p99_other_dt=float(np.percentile(g[~low], 99)) if (~low).any() else None,
        above=above, peaks=peaks,
    )


def as_dict(s: ReferenceStudy) -> dict:
    return asdict(s)


def describe(s: ReferenceStudy) -> str:
    """A few readable lines for the terminal."""
    e, k = s.explicit, s.peaks
    lines = [f"{Path(s.source).name}: {s.minutes} minutes (first hour left out)",
             f"  explicit flow G: mean {e['mean']:.2f}, p99 {e['p99']:.1f}, max {e['max']:.1f} m3 s-1"]
    if s.truth:
        t = s.truth
        lines.append(f"  true flow:       mean {t['mean']:.2f}, p99 {t['p99']:.1f}, "
                     f"max {t['max']:.1f} m3 s-1; r {s.r_truth:.2f}, "
                     f"MAE explicit vs truth {s.mae_truth:.2f} m3 s-1")
    lines.append(f"  c_ven_d median {s.c_ven_d_median:.3f}, c_ven_w median {s.c_ven_w_median:.3f} "
                 "(published 0.65 and 0.09)")
    if s.p99_low_dt is not None and s.p99_other_dt is not None:
        lines.append(f"  G p99 where |dT| < {LOW_DT_K} K: {s.p99_low_dt:.1f}; elsewhere {s.p99_other_dt:.1f}")
    lines.append(f"  peaks above {s.above:g} m3 s-1: {k.minutes} minutes")
    if k.minutes:
        if k.truth_mean is not None:
            lines.append(f"    true flow there: mean {k.truth_mean:.1f}, min {k.truth_min:.1f} m3 s-1")
        lines.append(f"    wind {k.wind:.1f} m s-1 (file {s.file_wind:.1f}), |dT| {k.abs_dt:.2f} K "
                     f"(file {s.file_abs_dt:.2f}), vents roof {k.vent_roof:.0f} % side {k.vent_side:.0f} %")
        lines.append(f"    c_ven_d {k.c_ven_d:.3f}, c_ven_w {k.c_ven_w:.3f} (medians at the peaks)")
        lines.append(f"    hours: {', '.join(k.hours)}")
    return "\n".join(lines)

"""The sensor over a whole kit CSV, and its score against the explicit (vent-based) estimate.

What ``python -m gateway vsensor`` does: replay the adaptive model without the vent signal
(its fluxes are the sensor's inputs), run the sensor step by step exactly as live, and, when
the CSV carries vent openings, replay the model with them too and score the closed-loop flow
and heat loss against that explicit estimate, beside the baselines shipped with the model.

The explicit estimate is the one the sensor learned: that of its metadata's
``target_model_kind`` when it has one (e.g. a prototype-fed sensor trained on the almeria
model's flow), else of the kind that feeds it. A CSV without a column that kind needs (t_soil
for almeria) still gets its flows; the score is left out with a note naming the column.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.metrics import metrics
from gateway.series import Series
from gateway.vsensor.adaptive import AdaptiveRun, explicit_model, has_vents, run_adaptive
from gateway.vsensor.features import heat_loss
from gateway.vsensor.runtime import SensorCounts, VentSensor

BASELINES = ("narx_no_pca", "linear_arx")
"""Baseline networks trained beside the PCA-NARX, written as ``<model>.<name>.onnx``."""
WARMUP_STEPS = 60
"""The first hour is left out of every score (the estimator and the sensor start cold)."""


@dataclass
class SensorRun:
    """One sensor's outputs over a series (length T)."""

    name: str
    flow: np.ndarray
    q_vent: np.ndarray
    valid: np.ndarray  # bool
    out_of_range: np.ndarray  # bool: some input outside the training ranges
    counts: SensorCounts


@dataclass
class BatchResult:
    time: np.ndarray
    runs: dict[str, SensorRun]  # "pca_narx" first, then the baselines found
    reference_flow: np.ndarray | None = None  # explicit flow [m3 s-1] when the CSV has vents
    reference_q: np.ndarray | None = None
    dt_in_out: np.ndarray | None = None
    notes: list[tuple[str, str]] = field(default_factory=list)
    """(code, message) of what the run says beside its figures: ``not_scored``,
    ``other_greenhouse``; the CLI makes them notes (gateway/cli/notes.py ``vsensor_notes``)."""
    reference_kind: str | None = None  # the model kind of the reference flow, when there is one


def run_sensor(sensor: VentSensor, novent: AdaptiveRun, name: str = "pca_narx") -> SensorRun:
    """Step ``sensor`` through a replay without vents, minute by minute, as live."""
    n = len(novent.time)
    cols = {k: novent.x.get(k, np.full(n, np.nan)) for k in ("t_in", "t_out", "rh_in", "rh_out", "wind")}
    names = list(novent.fluxes)
    flow, q, valid, oor = np.empty(n), np.empty(n), np.zeros(n, bool), np.zeros(n, bool)
    for t in range(n):
        est = sensor.step({k: v[t] for k, v in cols.items()}, {k: novent.fluxes[k][t] for k in names})
        flow[t], q[t], valid[t], oor[t] = est.flow, est.q_vent, est.valid, bool(est.out_of_range)
    return SensorRun(name, flow, q, valid, oor, sensor.counts)


def baseline_paths(model_path: str | Path) -> dict[str, Path]:
    """The baseline models that sit beside ``model_path``."""
    p = Path(model_path)
    found = {b: p.with_name(f"{p.stem}.{b}.onnx") for b in BASELINES}
    return {k: v for k, v in found.items() if v.exists()}


def unscored_reason(sensor: VentSensor, series: Series, gh: Greenhouse, kind: str) -> str | None:
    """Why ``series`` cannot be scored against the explicit flow the sensor learned (None: it
    can, or it has no vents to score against). The flow's kind is the metadata's
    ``target_model_kind``, else ``kind``."""
    if not has_vents(series):
        return None
    target = sensor.info.meta.get("target_model_kind") or kind
    missing = [c for c in explicit_model(target, gh).requires if c not in series]
    if not missing:
        return None
    return (f"not scored: the reference (the explicit flow the sensor learned) is the '{target}' "
            f"model's, which needs column(s) {', '.join(missing)}, absent from the CSV; the flows "
            "are the sensor's all the same")


def replays_needed(sensor: VentSensor, series: Series, gh: Greenhouse, kind: str) -> int:
    """How many adaptive replays ``run_series`` makes (a progress bar's size, in series)."""
    return 2 if has_vents(series) and unscored_reason(sensor, series, gh, kind) is None else 1


def run_series(model_path: str | Path, series: Series, gh: Greenhouse, kind: str,
               overrides=None, seed: int = 0, baselines: bool = True,
               progress: Callable[[int], None] | None = None,
               clamp_inputs: bool = False, sensor: VentSensor | None = None) -> BatchResult:
    """Everything ``python -m gateway vsensor`` computes (see the module docstring);
    ``clamp_inputs``: every sensor built with it (``VentSensor``); ``sensor``: the model
    already opened from ``model_path`` (else it is opened here)."""
    if sensor is None:
        sensor = VentSensor(model_path, gh, kind, clamp_inputs=clamp_inputs)
    if overrides is None:
        overrides = sensor.info.meta.get("online_overrides") or None
    novent = run_adaptive(kind, series, gh, vents=False, overrides=overrides, seed=seed, progress=progress)
    runs = {"pca_narx": run_sensor(sensor, novent, sensor.info.network)}
    if baselines:
        for name, path in baseline_paths(model_path).items():
            runs[name] = run_sensor(VentSensor(path, gh, kind, clamp_inputs=clamp_inputs),
                                    novent, name)
    dt = novent.x["t_in"] - novent.x["t_out"]
    result = BatchResult(series.time, runs, dt_in_out=dt)
    target = sensor.info.meta.get("target_model_kind") or kind
    unscored = unscored_reason(sensor, series, gh, kind)
    if unscored:
        result.notes.append(("not_scored", unscored))
    elif has_vents(series):
        vent = run_adaptive(target, series, gh, vents=True, overrides=overrides, seed=seed,
                            progress=progress)
        if vent.flow is None:  # run_adaptive computes it with the vents
            raise ValueError("the replay with the vents gave no explicit flow")
        result.reference_flow = vent.flow
        result.reference_q = heat_loss(vent.flow, dt, gh)
        result.reference_kind = target
    if sensor.mismatch:
        result.notes.append(("other_greenhouse",
                             "model trained on another greenhouse: " + "; ".join(sensor.mismatch)))
    return result


def _m(ref: np.ndarray, est: np.ndarray, keep: np.ndarray) -> dict[str, object] | None:
    ok = keep & np.isfinite(ref) & np.isfinite(est)
    m = metrics(ref[ok], est[ok])
    if m is None:
        return None
    span = float(ref[ok].max() - ref[ok].min())
    m.pop("ef", None)
    out: dict[str, object] = dict(m)
    out["range"] = [float(ref[ok].min()), float(ref[ok].max())]
    out["mae_pct_range"] = 100.0 * m["mae"] / span if span > 0 else None
    return out


def score(result: BatchResult, warmup: int = WARMUP_STEPS) -> dict:
    """The JSON report: per sensor ``{"flow": M, "q_vent": M, "flow_error_pct", "steps",
    "out_of_range", ...}`` with M = mae, rmse, maxae, r2, n, range, mae_pct_range (None
    without a reference)."""
    n = len(result.time)
    keep = np.arange(n) >= warmup
    out = {}
    for name, run in result.runs.items():
        c = run.counts
        block: dict[str, object] = {
            "steps": c.steps,
            "flagged": c.flagged,
            "out_of_range": c.out_of_range_steps,
            "out_of_range_by_input": dict(sorted(c.out_of_range.items())),
            "missing": c.missing_steps,
            "missing_by_input": dict(sorted(c.missing.items())),
            "clamped": c.clamped,
            "inputs_clamped": c.inputs_clamped,
            "flow": None, "q_vent": None, "flow_error_pct": None,
        }
        if result.reference_flow is not None:
            if result.reference_q is None:  # run_series sets both
                raise ValueError("a batch result with a reference flow but no reference heat loss")
            flow = _m(result.reference_flow, run.flow, keep)
            block["flow"] = flow
            block["q_vent"] = _m(result.reference_q, run.q_vent, keep)
            if flow:
                block["flow_error_pct"] = flow["mae_pct_range"]
        out[name] = block
    return out


def write_flows(result: BatchResult, path: str | Path) -> None:
    """CSV: time, flow [m3 s-1], heat loss [W m-2], out-of-range flag, valid flag (the main
    sensor), and the explicit flow when there is one."""
    main = next(iter(result.runs.values()))
    stamps = np.datetime_as_string(result.time.astype("datetime64[s]"), unit="s")
    header = "time,flow_m3_s,q_vent_w_m2,out_of_range,valid"
    ref = result.reference_flow
    if ref is not None:
        header += ",explicit_flow_m3_s"
    lines = [header]
    for i in range(len(stamps)):
        cells = [f"{stamps[i]}Z", f"{main.flow[i]:.6g}", f"{main.q_vent[i]:.6g}",
                 str(int(main.out_of_range[i])), str(int(main.valid[i]))]
        if ref is not None:
            cells.append("" if not np.isfinite(ref[i]) else f"{ref[i]:.6g}")
        lines.append(",".join(cells))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")

"""Where a sensor's closed-loop validation error comes from (``python -m training.vsensor errors``).

Runs a written model (ONNX, through onnxruntime) in closed loop over whole training files, as
the fit's validation does (``fit.simulate``: the same recurrence, inputs and physical limit),
and splits the absolute flow error on the validation quarter (the last 25 % of every file) by
file, wind, vent opening, hour of the day, the target's level and |T_in − T_out|. Each class
gets its minutes, its mean absolute error, its share of the summed error and its mean signed
error (estimate − explicit flow). Only the validation quarters are read: the held-out files play
no part in choosing what to try next.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.series import load_series
from gateway.vsensor.features import extras_of, flow_limits
from gateway.vsensor.loop import closed_loop, fill_missing, padded_ranges
from training.vsensor import fit
from training.vsensor.dataset import Segment, build_segment

WIND_BINS = (0.0, 2.0, 4.0, 6.0, 8.0, np.inf)  # [m s-1]
FLOW_BINS = (0.0, 5.0, 10.0, 20.0, 30.0, np.inf)  # explicit flow [m3 s-1]
DT_BINS = (0.0, 0.5, 1.0, 2.0, 4.0, np.inf)  # |T_in − T_out| [K]
HOUR_BINS = (0, 6, 9, 12, 15, 18, 21, 24)  # UTC
VENT_CLASSES = ("closed", "roof only", "side only", "both open")


@dataclass
class Row:
    label: str
    minutes: int
    mae: float  # [m3 s-1]
    share: float  # of the summed absolute error of the rows' population
    bias: float  # mean estimate − explicit flow [m3 s-1]


@dataclass
class Breakdown:
    title: str
    rows: list[Row]


def onnx_predict(model: str | Path):
    """``predict(u, y_past)`` of a written model (the graph's inputs ``u`` and ``y_past``)."""
    from gateway.vsensor.ort import load

    ort = load()

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(model), opts, providers=["CPUExecutionProvider"])

    def predict(u: np.ndarray, y_past: np.ndarray) -> np.ndarray:
        out = sess.run(None, {"u": u.astype(np.float32), "y_past": y_past.astype(np.float32)})
        return np.asarray(out[0], dtype=float).reshape(len(u), -1)  # (N, K): K output histories

    return predict, sess


def model_feature_names(model: str | Path) -> list[str]:
    """The input names in a written model's metadata (its extra features among them)."""
    import json

    import onnx

    props = {p.key: p.value for p in onnx.load(str(model)).metadata_props}
    return [f["name"] for f in json.loads(props["features"])]


def simulate_model(model: str | Path, segments: list[Segment], gh: Greenhouse, kind: str,
                   clamp_inputs: bool = False) -> list[np.ndarray]:
    """Closed-loop flows of the model over every whole segment (as ``fit.simulate``);
    ``clamp_inputs``: inputs clamped to the metadata's padded training ranges, as
    ``VentSensor(clamp_inputs=True)``."""
    import json

    predict, sess = onnx_predict(model)
    meta = sess.get_modelmeta().custom_metadata_map
    names = [f["name"] for f in json.loads(meta["features"])]  # the metadata's dicts are sorted
    mean = np.array([json.loads(meta["input_mean"])[n] for n in names], dtype=float)
    y0 = float(json.loads(meta["y0"]))
    ranges = json.loads(meta["training_ranges"])
    bounds = padded_ranges(np.array([ranges[n] for n in names])) if clamp_inputs else None
    limits = flow_limits(gh, kind)
    n_max = max(len(s.flow) for s in segments)
    u = np.empty((len(segments), n_max, segments[0].inputs.shape[1]))
    up = np.zeros((len(segments), n_max))
    for i, s in enumerate(segments):
        filled, _ = fill_missing(s.inputs, mean)
        u[i, : len(filled)] = filled
        u[i, len(filled):] = filled[-1]
        up[i, : len(filled)] = limits.upper(s.x["t_in"] - s.x["t_out"], s.x["t_out"], s.x["wind"])
    y = closed_loop(predict, u, up, y0, int(json.loads(meta.get("feedback_histories", "1"))),
                    bounds)
    return [y[i, : len(s.flow)] for i, s in enumerate(segments)]


def _vent_class(roof: np.ndarray, side: np.ndarray) -> np.ndarray:
    r, s = np.nan_to_num(roof) > 0.5, np.nan_to_num(side) > 0.5
    return np.select([~r & ~s, r & ~s, ~r & s], [0, 1, 2], 3)


def _bins(values: np.ndarray, edges, fmt: str) -> tuple[np.ndarray, list[str]]:
    idx = np.digitize(values, edges[1:-1])
    labels = [fmt.format(a, b) if np.isfinite(b) else fmt.split("–")[0].format(a) + "+"
              for a, b in zip(edges[:-1], edges[1:], strict=True)]
    return idx, labels


def _table(title: str, cls: np.ndarray, labels: list[str], err: np.ndarray) -> Breakdown:
    total = float(np.abs(err).sum()) or 1.0
    rows = []
    for j, lab in enumerate(labels):
        m = cls == j
        if m.any():
            rows.append(Row(lab, int(m.sum()), float(np.abs(err[m]).mean()),
                            float(np.abs(err[m]).sum()) / total, float(err[m].mean())))
    return Breakdown(title, rows)


def breakdowns(segments: list[Segment], sims: list[np.ndarray], vents: list[dict[str, np.ndarray]],
               only: str | None = None) -> list[Breakdown]:
    """Tables of the validation-quarter error: by file, then (over the files whose stem
    contains ``only``, or all) by wind, vents, hour, explicit flow and |ΔT|."""
    split = fit.make_split(segments, [np.zeros(len(s.flow)) for s in segments])
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("err", "wind", "vent", "hour", "flow", "dt", "file")}
    for i, (s, y, v, c) in enumerate(zip(segments, sims, vents, split.cut, strict=True)):
        if only is not None and only not in Path(s.source).stem:
            continue
        sl = slice(c, None)
        ok = np.isfinite(s.flow[sl])
        cols["err"].append((y[sl] - s.flow[sl])[ok])
        cols["wind"].append(np.nan_to_num(s.x["wind"][sl])[ok])
        cols["vent"].append(_vent_class(v["vent_roof"][sl], v["vent_side"][sl])[ok])
        cols["hour"].append(((s.time[sl].astype("int64") // 3600) % 24)[ok])
        cols["flow"].append(s.flow[sl][ok])
        cols["dt"].append(np.abs(np.nan_to_num(s.x["t_in"][sl] - s.x["t_out"][sl]))[ok])
        cols["file"].append(np.full(int(ok.sum()), i))
    a = {k: np.concatenate(v) for k, v in cols.items()}
    err = a["err"]
    stems = [Path(s.source).stem for s in segments]
    out = [_table("file", a["file"], stems, err)]
    for title, key, edges, fmt in (("wind [m s-1]", "wind", WIND_BINS, "{:g}–{:g}"),
                                   ("explicit flow [m3 s-1]", "flow", FLOW_BINS, "{:g}–{:g}"),
                                   ("|T_in - T_out| [K]", "dt", DT_BINS, "{:g}–{:g}"),
                                   ("hour (UTC)", "hour", HOUR_BINS, "{:g}–{:g} h")):
        idx, labels = _bins(a[key], edges, fmt)
        out.append(_table(title, idx, labels, err))
    out.append(_table("vents", a["vent"], list(VENT_CLASSES), err))
    return out


def study(model: str | Path, paths: list[str], gh: Greenhouse, kind: str, cache, overrides,
          seed: int, only: str | None = None, target_kind: str | None = None,
          progress: Callable[..., None] | None = None) -> list[Breakdown]:
    """The breakdowns of ``model`` over ``paths``. ``progress(advance=1, info="",
    description=None)`` (gateway/cli/progress.py's callback) counts ``len(paths) + 1`` steps:
    each file's replays (their rows as info), then the closed loop over all of them."""
    progress = progress or (lambda **k: None)
    extra = extras_of(kind, model_feature_names(model))
    segments = []
    for p in paths:
        progress(advance=0, description=f"replays {Path(p).name}")
        segments.append(build_segment(p, gh, kind, cache, overrides, seed,
                                      progress=lambda done: progress(advance=0, info=f"row {done}"),
                                      extra=extra, target_kind=target_kind))
        progress(advance=1)
    vents = []
    for p in paths:
        series = load_series(str(p), step=60.0)
        vents.append({k: series[k] if k in series.columns else np.zeros(len(series))
                      for k in ("vent_roof", "vent_side")})
    progress(advance=0, description="closed loop")
    sims = simulate_model(model, segments, gh, kind)
    progress(advance=1)
    return breakdowns(segments, sims, vents, only)


def describe(tables: list[Breakdown]) -> str:
    lines = []
    for t in tables:
        lines += [f"by {t.title}:", f"  {'class':<30} {'minutes':>7} {'MAE':>7} {'share':>6} {'bias':>7}"]
        lines += [f"  {r.label:<30} {r.minutes:>7d} {r.mae:>7.3f} {100 * r.share:>5.1f}% {r.bias:>+7.3f}"
                  for r in t.rows]
    return "\n".join(lines)

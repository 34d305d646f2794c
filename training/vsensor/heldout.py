"""Held-out files scored after training: the figures ``python -m gateway vsensor`` prints.

``train --test FILE...`` runs the three written models (through the gateway's own runtime,
``VentSensor``, closed loop, minute by minute) on files the fit never saw, against the explicit
flow of the same replays (cached like the training files'), and puts the table in the model
card. Nothing here feeds back into the fit or the choice of settings: selection is on the
validation quarter of the training files only.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.vsensor.adaptive import AdaptiveRun
from gateway.vsensor.batch import BatchResult, run_sensor, score
from gateway.vsensor.features import heat_loss
from gateway.vsensor.runtime import VentSensor
from training.vsensor.dataset import Segment

LABELS = {"pca_narx": "PCA-NARX", "narx_no_pca": "NARX without PCA", "linear_arx": "linear ARX"}


def score_segment(seg: Segment, models: dict[str, Path], gh: Greenhouse, kind: str,
                  clamp_inputs: bool = False,
                  progress: Callable[..., None] | None = None) -> dict:
    """``score()`` of every model on one held-out segment (same keys as the CLI's JSON).
    ``progress(advance=1, info="")`` after each model's run (minute by minute, seconds each)."""
    nov = AdaptiveRun(seg.time, seg.x, seg.fluxes, np.empty((len(seg.time), 0)), [])
    runs = {}
    for name, path in models.items():
        runs[name] = run_sensor(VentSensor(path, gh, kind, clamp_inputs=clamp_inputs), nov, name)
        if progress is not None:
            progress(advance=1, info=Path(path).name)
    dt = seg.x["t_in"] - seg.x["t_out"]
    ref = seg.flow  # NaN in the first hour, which score() leaves out anyway
    return score(BatchResult(seg.time, runs, ref, heat_loss(ref, dt, gh), dt))


def table(scores: dict[str, dict]) -> str:
    """Markdown: one row per file and network (flow MAE, % of range, RMSE, R², heat-loss MAE)."""
    lines = ["| file | network | flow MAE [m3 s-1] | % of range | RMSE | R² | heat-loss MAE [W m-2] "
             "| out-of-range steps |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for file, per in scores.items():
        for i, (name, s) in enumerate(per.items()):
            f, q = s["flow"], s["q_vent"]
            head = f"{file}, range {f['range'][0]:.1f}–{f['range'][1]:.1f}" if i == 0 else ""
            lines.append(f"| {head} | {LABELS.get(name, name)} | {f['mae']:.2f} | "
                         f"{f['mae_pct_range']:.2f} | {f['rmse']:.2f} | {f['r2']:.2f} | {q['mae']:.2f} "
                         f"| {s['out_of_range']} |")
    return "\n".join(lines) + "\n"

"""What a virtual ventilation sensor model says about itself, and whether this code can feed it.

The ONNX file's metadata (written by training/vsensor/export.py) names the features, their
units and filter time constants, the delays, the step, the training ranges, the model kind the
fluxes come from and what the network predicts. :func:`read_info` reads it once at load;
:func:`check_model` and :func:`check_target` raise :class:`ModelMismatch`, naming the file and
the difference, when it does not match what gateway/vsensor/features.py computes
(docs/vsensor.md, "Run time"). Split from runtime.py, which loads the model and steps it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.vsensor.features import (
    EXTRAS,
    INPUT_DELAYS,
    OUTPUT_DELAYS,
    STEP_S,
    check_names,
    extras_of,
    features,
)

FORMAT = "serra-vsensor/1"
TARGET_KINDS = ("flow", "opening", "mixed")
"""What the graph's network predicts (metadata ``target_kind``, absent: ``flow``); either way the
graph takes past flows and gives a flow. ``opening``: G / D, the graph computing the ventilation
driver D from its inputs with the constants of ``opening_driver`` (docs/vsensor.md). ``mixed``:
an ensemble whose members learn ``member_targets`` (each ``flow`` or ``opening``), averaged as
flows in the graph."""
MEMBER_TARGETS = ("flow", "opening")


class ModelMismatch(ValueError):
    """The ONNX model does not fit the code that would feed it; the message says how."""




@dataclass(frozen=True)
class ModelInfo:
    """What the model's metadata says (read once at load)."""

    path: str
    kind: str  # model kind the fluxes come from
    network: str  # pca_narx | narx_no_pca | linear_arx
    names: tuple[str, ...]
    ranges: np.ndarray  # (F, 2) training min, max of each filtered input
    mean: np.ndarray  # (F,) training mean (stands in for an input never seen)
    y0: float  # past outputs before the first step [m3 s-1]
    greenhouse: dict
    meta: dict


def read_info(path: str | Path, session) -> ModelInfo:
    raw = dict(session.get_modelmeta().custom_metadata_map)
    if raw.get("format") != FORMAT:
        raise ModelMismatch(f"{path}: not a Serra ventilation sensor model (format "
                            f"{raw.get('format')!r}, expected {FORMAT!r})")
    meta = {k: (v if k == "format" else _json(v)) for k, v in raw.items()}
    missing = [k for k in ("features", "model_kind", "training_ranges", "input_mean", "y0") if k not in meta]
    if missing:
        raise ModelMismatch(f"{path}: metadata lacks {', '.join(missing)}")
    feats = meta["features"]
    names = tuple(f.get("name", "?") for f in feats)
    nan2 = [math.nan, math.nan]
    return ModelInfo(
        path=str(path), kind=meta["model_kind"], network=meta.get("network", "?"), names=names,
        ranges=np.array([meta["training_ranges"].get(n, nan2) for n in names], dtype=float),
        mean=np.array([meta["input_mean"].get(n, math.nan) for n in names], dtype=float),
        y0=float(meta["y0"]), greenhouse=meta.get("greenhouse", {}), meta=meta,
    )


def _json(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


def check_model(info: ModelInfo, kind: str, n_graph_features: int | None = None) -> None:
    """Raise :class:`ModelMismatch` unless the model reads what this code computes for ``kind``
    (with the extra features the model names, when the code knows them)."""
    where = info.path
    if info.kind != kind:
        raise ModelMismatch(f"{where}: trained on fluxes of the '{info.kind}' model, but the "
                            f"gateway runs the '{kind}' model")
    extra = tuple(n for n in extras_of(kind, info.names) if n in EXTRAS)
    code = features(kind, extra)
    diff = check_names([f.name for f in code], info.names)
    if diff:
        raise ModelMismatch(f"{where}: {diff} (model kind '{kind}')")
    meta_feats = info.meta["features"]
    for f, m in zip(code, meta_feats, strict=True):
        if f.unit != m.get("unit"):
            raise ModelMismatch(
                f"{where}: feature {f.name} in {m.get('unit')!r}, the code gives {f.unit!r}")
        if not math.isclose(f.tau, float(m.get("tau_s", -1)), abs_tol=1e-9):
            raise ModelMismatch(f"{where}: feature {f.name} filtered with tau {m.get('tau_s')} s, "
                                f"the code uses {f.tau:g} s")
    for key, value in (("input_delays", INPUT_DELAYS), ("output_delays", OUTPUT_DELAYS)):
        if list(info.meta.get(key, [])) != list(value):
            raise ModelMismatch(
                f"{where}: {key} {info.meta.get(key)} but the code feeds {list(value)}")
    if float(info.meta.get("step_s", -1)) != STEP_S:
        raise ModelMismatch(
            f"{where}: trained at a {info.meta.get('step_s')} s step, the code runs {STEP_S:g} s")
    bad = [n for n, r, m in zip(info.names, info.ranges, info.mean, strict=True)
           if not (np.all(np.isfinite(r)) and np.isfinite(m))]
    if bad:
        raise ModelMismatch(f"{where}: no training range or mean for {', '.join(bad)}")
    if n_graph_features is not None and n_graph_features != len(code):
        raise ModelMismatch(
            f"{where}: the graph takes {n_graph_features} inputs, the metadata names {len(code)}")
    check_target(info)


def check_target(info: ModelInfo, gh: Greenhouse | None = None) -> None:
    """Raise :class:`ModelMismatch` for a target kind this code does not serve, a mixed model
    whose members' targets it does not, or an opening (or mixed) model whose driver is not the
    model layer's (``ventilation_driver``) for ``gh``, the house it was trained on (checked when
    ``gh`` is that house: a changed III.31 needs a retrain)."""
    kind = info.meta.get("target_kind", "flow")
    if kind not in TARGET_KINDS:
        raise ModelMismatch(f"{info.path}: target kind {kind!r}, this code serves {TARGET_KINDS}")
    if kind == "mixed" and not _mixed_needs_driver(info):  # flow members only: no driver
        return
    if kind == "flow":
        return
    drv = info.meta.get("opening_driver")
    if not isinstance(drv, dict) or not all(k in drv for k in ("b", "w", "floor", "t_out_ref_c",
                                                               "floor_wind_m_s")):
        raise ModelMismatch(f"{info.path}: an opening model without its driver's constants")
    if gh is None:
        return
    from gateway.model.almeria import driver_constants

    code = dict(zip(("b", "w", "floor"), driver_constants(gh, float(drv["t_out_ref_c"]),
                                                          float(drv["floor_wind_m_s"])),
                    strict=True))
    for k, v in code.items():
        if not math.isclose(float(drv[k]), v, rel_tol=1e-6):
            raise ModelMismatch(f"{info.path}: opening driver {k} {drv[k]} but the model layer "
                                f"gives {v:.6g} for this house: retrain")


def _mixed_needs_driver(info: ModelInfo) -> bool:
    """Raise :class:`ModelMismatch` unless a mixed model names its members' targets (two or
    more, each one this code serves, one per output history with own feedback); True when one
    of them is an opening member (whose driver is then checked)."""
    members = info.meta.get("member_targets")
    if not isinstance(members, list) or len(members) < 2:
        raise ModelMismatch(f"{info.path}: a mixed model without its members' targets")
    bad = sorted({str(m) for m in members} - set(MEMBER_TARGETS))
    if bad:
        raise ModelMismatch(f"{info.path}: member target {', '.join(bad)}, this code serves "
                            f"{MEMBER_TARGETS}")
    k = int(info.meta.get("feedback_histories", 1))
    if k > 1 and k != len(members):
        raise ModelMismatch(f"{info.path}: {len(members)} member targets for {k} output histories")
    return "opening" in members



def graph_histories(path: str | Path, session, info: ModelInfo) -> int:
    """Output histories the graph keeps: 1 (``y_past`` (N, 5)), or K for an ensemble whose
    members each hear their own past (``y_past`` (N, K, 5), metadata ``feedback_histories``)."""
    shape = next(i.shape for i in session.get_inputs() if i.name == "y_past")
    k = shape[1] if len(shape) == 3 else 1
    want = int(info.meta.get("feedback_histories", 1))
    if not isinstance(k, int) or k != want:
        raise ModelMismatch(f"{path}: the graph keeps {k} output histories, the metadata says {want}")
    return k



"""Dataset builder: a kit CSV with vent openings → the sensor's inputs and target (§IV.3.1.1).

For each file the adaptive model runs twice (gateway/vsensor/adaptive.py): with the vent
signal (its ventilation flow G, III.31–32, is the target [m3 s-1]) and without it (its heat
fluxes, with wind and the inside–outside temperature and humidity differences, are the
inputs). Both replays take minutes per week of data, so their products are cached in
``cache_dir`` under a key made of the file's bytes, the greenhouse, the model kind, the
online settings, this module's version and the model layer's code probe (gateway/vsensor/
probe.py: a changed flux term, sky temperature or step replays again): a second ``train`` on
the same files only reads.

``target_kind`` (``train --target-kind``): the inputs come from the ``kind`` model's no-vent
replay (cached alone, under its own key) and the target from the ``target_kind`` model's
replay with the vents (its usual cache entry): e.g. a sensor fed by the kit-only prototype
model that learns the almeria model's flow, which needs t_soil only at training time.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import build_model
from gateway.model.model import check_columns
from gateway.series import Series, load_series
from gateway.vsensor.adaptive import Overrides, explicit_model, has_vents, run_adaptive, settings_for
from gateway.vsensor.features import feature_names, filter_gains, heat_loss, low_pass, raw_features
from gateway.vsensor.probe import code_probe

CACHE_VERSION = 2
KEEP = ("t_in", "t_out", "rh_in", "rh_out", "wind", "i_glob")
"""Drivers kept beside the fluxes (the report's day classes and the heat loss need them)."""
WARMUP_STEPS = 60
"""The first hour of each file is left out: the estimator is still settling."""


@dataclass
class Segment:
    """One file's data on its time grid (length T)."""

    source: str
    sha256: str  # of the CSV's bytes
    time: np.ndarray
    raw: np.ndarray  # (T, F) unfiltered inputs
    inputs: np.ndarray  # (T, F) low-pass filtered inputs: what the sensor reads
    flow: np.ndarray  # (T,) target: the explicit ventilation flow G [m3 s-1]
    q_vent: np.ndarray  # (T,) its heat loss [W m-2] (III.32)
    x: dict[str, np.ndarray]  # KEEP drivers
    fluxes: dict[str, np.ndarray] = field(default_factory=dict)  # no-vent replay's fluxes [W m-2]


def file_sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cache_key(csv_sha: str, gh: Greenhouse, kind: str, overrides: Overrides | None, seed: int,
              part: str = "") -> str:
    """``part``: "" for both replays (the keys written before it existed), "novent" for the
    no-vent replay alone."""
    gh_text = Path(gh.source).read_bytes().hex() if Path(gh.source).exists() else repr(gh)
    settings = {g: {k: float(v) for k, v in t.items()} for g, t in (overrides or {}).items()}
    probe = code_probe(kind, gh)  # a change of the model layer's fluxes or step: replay again
    items = [CACHE_VERSION, csv_sha, gh_text, kind, settings, seed, probe] + ([part] if part else [])
    blob = json.dumps(items, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


def load_checked(path: str | Path, gh: Greenhouse, kind: str, vents: bool = True) -> Series:
    """The resampled CSV, refused with a clear error when it cannot give a target (``vents``
    False: only the no-vent replay's inputs are wanted)."""
    model = explicit_model(kind, gh) if vents else build_model(kind, gh)
    series = load_series(str(path), step=60.0, required=build_model(kind, gh).requires)
    check_columns(model, [c for c in series.columns if c in series], str(path))
    if vents and not has_vents(series):
        raise ValueError(f"{path}: no vent_roof or vent_side values: the training target (the "
                         "explicit, vent-based flow) needs the vent openings")
    if len(series) <= WARMUP_STEPS + 10:
        raise ValueError(f"{path}: {len(series)} one-minute samples; need more than {WARMUP_STEPS + 10}")
    return series


def build_segment(
    path: str | Path,
    gh: Greenhouse,
    kind: str,
    cache_dir: str | Path | None = None,
    overrides: Overrides | None = None,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
    extra: tuple[str, ...] = (),
    target_kind: str | None = None,
) -> Segment:
    """Inputs and target of one kit CSV (cached). ``progress(rows)`` during the replays;
    ``extra``: the optional derived inputs (features.EXTRAS) after the base ones (computed
    from the cached replays: not part of the cache key); ``target_kind``: the model whose
    vent replay gives the target (default ``kind``; see the module docstring)."""
    settings_for(build_model(kind, gh), gh, overrides)  # bad overrides fail before minutes of work
    sha = file_sha256(path)
    if target_kind is None or target_kind == kind:
        arrays = _replays(path, sha, gh, kind, cache_dir, overrides, seed, progress, vents=True)
        return _segment(str(path), sha, arrays, gh, kind, extra)
    settings_for(build_model(target_kind, gh), gh, overrides)
    target = _replays(path, sha, gh, target_kind, cache_dir, overrides, seed, progress, vents=True)
    arrays = _replays(path, sha, gh, kind, cache_dir, overrides, seed, progress, vents=False)
    if not np.array_equal(arrays["time"], target["time"]):  # same CSV, same grid: a guard
        raise ValueError(f"{path}: the {kind} and {target_kind} replays have different time grids")
    return _segment(str(path), sha, {**arrays, "flow": target["flow"]}, gh, kind, extra)


def _replays(path: str | Path, sha: str, gh: Greenhouse, kind: str, cache_dir, overrides,
             seed: int, progress, vents: bool) -> dict[str, np.ndarray]:
    """The cached products of one file's replays: with ``vents`` both (the flow, and the
    no-vent fluxes and drivers), without them the no-vent replay alone (no ``flow``)."""
    cache = None
    if cache_dir is not None:
        key = cache_key(sha, gh, kind, overrides, seed, "" if vents else "novent")
        cache = Path(cache_dir) / f"{Path(path).stem}-{key}.npz"
    if cache is not None and cache.exists():
        with np.load(cache) as data:
            return {k: data[k] for k in data.files}
    series = load_checked(path, gh, kind, vents)
    novent = run_adaptive(kind, series, gh, vents=False, overrides=overrides, seed=seed,
                          progress=progress)
    arrays = {"time": series.time.astype(np.int64)}
    if vents:
        arrays["flow"] = run_adaptive(kind, series, gh, vents=True, overrides=overrides,
                                      seed=seed, progress=progress).flow
    arrays.update({f"flux_{k}": v for k, v in novent.fluxes.items()})
    arrays.update({f"x_{k}": novent.x.get(k, np.full(len(series), np.nan)) for k in KEEP})
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        # a name of this process's own (two runs sharing the cache folder, two trainings or the
        # test workers, may write the same entry at once; the rename is atomic either way) that
        # does not end in .npz, so a look for entries (*.npz) never sees one half written
        tmp = cache.with_name(f"{cache.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:  # a file object: savez adds no .npz to the name
            np.savez_compressed(f, **arrays)
        tmp.replace(cache)
    return arrays


def _segment(source: str, sha: str, a: dict[str, np.ndarray], gh: Greenhouse, kind: str,
             extra: tuple[str, ...] = ()) -> Segment:
    x = {k: a[f"x_{k}"] for k in KEEP}
    fluxes = {k[5:]: v for k, v in a.items() if k.startswith("flux_")}
    raw = raw_features(kind, x, fluxes, extra)
    inputs = low_pass(raw, filter_gains(kind, extra=extra))
    flow = a["flow"].astype(float).copy()
    flow[:WARMUP_STEPS] = np.nan
    return Segment(
        source=source, sha256=sha, time=a["time"].astype("datetime64[s]"), raw=raw,
        inputs=inputs, flow=flow, q_vent=heat_loss(flow, x["t_in"] - x["t_out"], gh), x=x,
        fluxes=fluxes,
    )


def fingerprint(segments: list[Segment], kind: str, extra: tuple[str, ...] = ()) -> str:
    """sha256 over the feature names and every input and target value (float64 bytes)."""
    h = hashlib.sha256(json.dumps(feature_names(kind, extra)).encode())
    for s in segments:
        h.update(np.ascontiguousarray(s.inputs, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(s.flow, dtype=np.float64).tobytes())
    return h.hexdigest()

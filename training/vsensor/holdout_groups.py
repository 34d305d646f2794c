"""Leave one site and season out: a setting judged on houses, sites and seasons it never saw.

``tune --holdout-groups`` groups the training files by site × season from their names
(``almeria-early-winter-grower`` → ``almeria-winter``; every ``twonode-…`` file → ``twonode``;
the vents' owner, ``grower`` or ``controller``, and ``early-``/``late-`` do not split a group).
For each group (a fold) the PCA-NARX is fitted as ``train`` would fit it on **the other
groups' files** (their own 75/25 split steers the early stopping and the closed-loop rounds;
standardisation and PCA refitted on them), then run in closed loop over **the whole of every
held-out file** (from its first minute, scored after the first hour, as the gateway scores a
file) against the explicit flow. Per fold: MAE and % of range over all its files, over its
grower's files and its controller's files apart (range: of those files' explicit flow).

The selection figure (docs/vsensor.md, "Seventh pass") is ``criterion``: the mean over the
folds of the grower's files' MAE, and the same over the controller's files, averaged: the
goal's two kinds of vents weighted alike. (``criterion_pct``, the same on % of range, was the
rule first written down: three held-out controller files barely ventilate, so their % of range
is large for a tiny error.)

``clamp``: the same fitted networks also run with every input clamped to the fold's padded
training ranges (``loop.padded_ranges`` of the ranges its model's metadata would carry), paired
with the unclamped run: ``Fold.clamped`` and ``own_clamped`` (docs/vsensor.md, tenth pass).

``Fold.signed_by_file``: per held-out file, the closed-loop mean signed error (sensor −
reference) [m3 s-1] of each run above (keys as ``Fold``'s score fields: ``scores``, ``own``,
``clamped``, ``own_clamped``): a sensor that sits under the reference shows it here, which its
MAE alone does not (kt's candidate: MAE 5.09 on Biskra's grower file, almost all bias).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from training.vsensor import fit
from training.vsensor.dataset import Segment
from training.vsensor.narx import Narx

SEASONS = ("winter", "spring", "summer", "autumn")
Fitter = Callable[[fit.Split, np.ndarray, np.ndarray, np.ndarray], Narx]
"""(split, mean, std, loadings) → the fitted PCA-NARX (what ``tune`` fits, fixed settings)."""


def group_of(stem: str) -> str:
    """Site × season of a corpus file name (``twonode`` files: one group of their own)."""
    parts = stem.split("-")
    if parts[0] == "twonode":
        return "twonode"
    season = next((p for p in parts[1:] if p in SEASONS), None)
    return f"{parts[0]}-{season}" if season else parts[0]


def vents_of(stem: str) -> str:
    """``grower`` (vents moved by hand) or ``controller``, from a corpus file name."""
    return "grower" if "grower" in stem else "controller"


def file_groups(stems: list[str]) -> dict[str, list[str]]:
    """Group → its stems, groups in the order of their first file."""
    out: dict[str, list[str]] = {}
    for s in stems:
        out.setdefault(group_of(s), []).append(s)
    return out


@dataclass
class Score:
    """Closed-loop flow error over some files' scored minutes."""

    mae: float  # [m3 s-1]
    pct_range: float  # MAE as % of the explicit flow's range over those minutes
    n: int
    range: tuple[float, float]


def score(refs: list[np.ndarray], ests: list[np.ndarray]) -> Score | None:
    """Pooled MAE and % of range of ``ests`` against ``refs`` (NaN references left out)."""
    if not refs:
        return None
    ref, est = np.concatenate(refs), np.concatenate(ests)
    ok = np.isfinite(ref)
    if not ok.any():
        return None
    mae = float(np.mean(np.abs(est[ok] - ref[ok])))
    lo, hi = float(ref[ok].min()), float(ref[ok].max())
    return Score(mae, 100.0 * mae / (hi - lo) if hi > lo else float("nan"), int(ok.sum()), (lo, hi))


def signed_error(ref: np.ndarray, est: np.ndarray) -> float:
    """Mean of ``est − ref`` [m3 s-1] over the finite references (the minutes ``score`` scores)."""
    ok = np.isfinite(ref)
    return float(np.mean(est[ok] - ref[ok])) if ok.any() else float("nan")


def signed_by_file(segments: list[Segment], sims: list[np.ndarray]) -> dict[str, float]:
    """Held-out stem → closed-loop mean signed error (sensor − reference) [m3 s-1]."""
    return {Path(s.source).stem: signed_error(s.flow, y) for s, y in zip(segments, sims, strict=True)}


def score_files(segments: list[Segment], sims: list[np.ndarray]) -> dict[str, Score | None]:
    """``all``, ``grower`` and ``controller`` (by the file names) scores of whole files."""
    stems = [Path(s.source).stem for s in segments]
    out = {}
    for key, keep in (("all", lambda v: True), ("grower", lambda v: v == "grower"),
                      ("controller", lambda v: v == "controller")):
        idx = [i for i, st in enumerate(stems) if keep(vents_of(st))]
        out[key] = score([segments[i].flow for i in idx], [sims[i] for i in idx])
    return out


@dataclass
class Fold:
    group: str
    held_out: list[str]  # stems
    trained_on: list[str]
    components: int
    scores: dict[str, Score | None]  # all / grower / controller, the members on the ensemble's past
    own: dict[str, Score | None] | None  # the same members each on its own past (K > 1)
    by_file: dict[str, float]  # held-out stem → MAE (ensemble's past)
    seconds: float
    clamped: dict[str, Score | None] | None = None  # ``scores`` with the inputs clamped
    own_clamped: dict[str, Score | None] | None = None  # ``own`` with the inputs clamped
    # run (``scores``/``own``/``clamped``/``own_clamped``) → held-out stem → mean(sensor − ref)
    signed_by_file: dict[str, dict[str, float]] = field(default_factory=dict)


def run_fold(group: str, segments: list[Segment], gh: Greenhouse, kind: str, seed: int,
             pca_variance: float, extra: tuple[str, ...], fitter: Fitter,
             clamp: bool = False) -> Fold:
    """Fit on the files outside ``group`` and score the whole files inside it (``clamp``: also
    with the inputs clamped, the same networks)."""
    from training.vsensor.train import prepare_segments, upper_limits

    t0 = time.perf_counter()
    inside = [s for s in segments if group_of(Path(s.source).stem) == group]
    outside = [s for s in segments if group_of(Path(s.source).stem) != group]
    if not inside or not outside:
        raise ValueError(f"group {group!r}: needs files inside and outside it")
    prep = prepare_segments(outside, gh, kind, seed, pca_variance, extra)
    net = fitter(prep.split, prep.mean, prep.std, prep.loadings)
    held = fit.Split(inside, upper_limits(inside, gh, kind), [0] * len(inside))
    shared = fit.simulate(_shared(net), held)
    own = fit.simulate_own_feedback(net, held) if len(net.members) > 1 else None
    stems = [Path(s.source).stem for s in inside]
    by_file = {st: score([s.flow], [y]).mae for st, s, y in zip(stems, inside, shared, strict=True)}
    fold = Fold(group, stems, [Path(s.source).stem for s in outside], int(prep.loadings.shape[1]),
                score_files(inside, shared), None if own is None else score_files(inside, own),
                by_file, 0.0)
    fold.signed_by_file["scores"] = signed_by_file(inside, shared)
    if own is not None:
        fold.signed_by_file["own"] = signed_by_file(inside, own)
    if clamp:  # the bounds the fold's written model would carry
        bounds = prep.input_bounds()
        sims = fit.simulate(_shared(net), held, bounds)
        fold.clamped = score_files(inside, sims)
        fold.signed_by_file["clamped"] = signed_by_file(inside, sims)
        if own is not None:
            sims = fit.simulate_own_feedback(net, held, bounds)
            fold.own_clamped = score_files(inside, sims)
            fold.signed_by_file["own_clamped"] = signed_by_file(inside, sims)
    fold.seconds = time.perf_counter() - t0
    return fold


def _shared(net: Narx) -> Narx:
    import dataclasses

    return dataclasses.replace(net, own_feedback=False)


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _run(f: Fold, own: bool, clamped: bool) -> str:
    """The ``Fold`` field of the run asked for: the ensemble's past or (``own``, when scored)
    each member's, inputs clamped or not."""
    run, own_run = ("clamped", "own_clamped") if clamped else ("scores", "own")
    return own_run if own and getattr(f, own_run) is not None else run


def pick(f: Fold, own: bool = False, clamped: bool = False) -> dict[str, Score | None]:
    """A fold's scores: the ensemble's past or (``own``) each member's, inputs clamped or not
    (``clamped``: None when the fold was not scored clamped)."""
    return getattr(f, _run(f, own, clamped))


def pick_signed(f: Fold, own: bool = False, clamped: bool = False) -> dict[str, float]:
    """The signed errors per file of the run ``pick`` picks (empty if not scored)."""
    return f.signed_by_file.get(_run(f, own, clamped), {})


def summarise(folds: list[Fold], own: bool = False, clamped: bool = False) -> dict:
    """Means over the folds (grower and controller apart) and the selection ``criterion``;
    ``own``: the figures of the members each on its own past; ``clamped``: with the inputs
    clamped (the folds must have been scored so)."""
    out: dict[str, float | None] = {}
    for key in ("all", "grower", "controller"):
        got = [s for s in (pick(f, own, clamped)[key] for f in folds) if s is not None]
        out[f"{key}_mae"] = _mean([s.mae for s in got])
        out[f"{key}_pct"] = _mean([s.pct_range for s in got])
    for name, unit in (("criterion", "mae"), ("criterion_pct", "pct")):
        g, c = out[f"grower_{unit}"], out[f"controller_{unit}"]
        out[name] = None if g is None or c is None else (g + c) / 2
    return out


def as_dict(fold: Fold) -> dict:
    return asdict(fold)


def describe(folds: list[Fold], own: bool, clamped: bool = False) -> str:
    """A Markdown table: one row per fold (MAE and % of range; grower and controller apart; the
    mean signed error of every held-out file)."""
    def cell(s: Score | None) -> str:
        return "—" if s is None else f"{s.mae:.3f} ({s.pct_range:.2f} %)"

    lines = ["| held-out group (files) | all | grower's files | controller's files "
             "| mean signed error per file (sensor − reference) [m3 s-1] |",
             "| --- | --- | --- | --- | --- |"]
    for f in folds:
        sc = pick(f, own, clamped)
        signed = ", ".join(f"{st} {e:+.3f}" for st, e in pick_signed(f, own, clamped).items())
        lines.append(f"| {f.group} ({len(f.held_out)}) | {cell(sc['all'])} | "
                     f"{cell(sc['grower'])} | {cell(sc['controller'])} | {signed or '—'} |")
    m = summarise(folds, own, clamped)

    def mean_cell(key: str) -> str:
        mae, pct = m[f"{key}_mae"], m[f"{key}_pct"]
        return "—" if mae is None else f"{mae:.3f} ({pct:.2f} %)"

    lines.append(f"| mean over folds | {mean_cell('all')} | {mean_cell('grower')} | "
                 f"{mean_cell('controller')} | |")
    crit, pct = m["criterion"], m["criterion_pct"]
    lines.append("\ncriterion (mean of the grower's and the controller's mean MAE): "
                 + ("—" if crit is None else f"{crit:.3f} m3 s-1 (on % of range: {pct:.2f} %)"))
    return "\n".join(lines)

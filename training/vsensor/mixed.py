"""The mixed ensemble (docs/vsensor.md, ninth pass, candidate F): ``--target mixed``.

The members alternate target by network seed (``narx.member_target``): even seeds learn the
flow G, odd seeds the effective opening G / D of the eighth pass. Each member is fitted exactly
as it would be in a one-target ensemble of the same settings (``fit.fit_narx`` with the same
seed and the row options of its own target: the shipped setting's members and ``--target
opening``'s), so member j of a mixed ensemble is bit for bit member j of one of those two. The
members share the standardisation and PCA (neither depends on the target) and are averaged as
flows (``narx.MixedNarx``; one ONNX graph, training/vsensor/export.py): the runtime still
feeds past flows and reads a flow.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from training.vsensor import fit
from training.vsensor.narx import MIXED, MixedNarx, member_target


def check_settings(target: str, ensemble: int, feedback: str) -> None:
    """Refuse, before any replay or fit, a mixed target the fit cannot serve."""
    if target != MIXED:
        return
    if ensemble < 2:
        raise ValueError("the mixed target needs an ensemble of at least 2 networks (--ensemble)")
    if feedback != "member":
        raise ValueError("the mixed target fits its members apart (--feedback member)")


def member_options(opts: fit.RowOptions, seed: int) -> fit.RowOptions:
    """The row options of a mixed ensemble's member of seed ``seed``: the mixed options with
    that member's own target (and the driver only for an opening member)."""
    target = member_target(seed)
    return dataclasses.replace(opts, target=target,
                               driver=opts.driver if target == "opening" else None)


def fit_mixed(name: str, split: fit.Split, mean, std, projection, seeds: list[int], hidden,
              epochs: int, rounds: int, round_epochs: int, progress: fit.Progress,
              round_lr: float | None, opts: fit.RowOptions,
              feedback: str = "member") -> tuple[MixedNarx, dict]:
    """Fit every member on its own (its own closed-loop rounds, as ``fit.fit_ensemble`` does for
    ``feedback`` "member"), then average them as flows. The log is ``fit_ensemble``'s, with the
    members' targets."""
    check_settings(MIXED, len(seeds), feedback)
    fitted = [fit.fit_narx(name, split, mean, std, projection, s, hidden, epochs, rounds,
                           round_epochs, progress, round_lr, member_options(opts, s))
              for s in seeds]
    log: dict[str, Any] = {"seeds": list(seeds), "targets": [member_target(s) for s in seeds],
           "members": [lg for _, lg in fitted],
           "member_val_mae": [min(lg["closed_loop_val_mae"]) for _, lg in fitted],
           "ensemble_val_mae_by_size": []}
    for k in range(1, len(fitted) + 1):
        part = MixedNarx(name, [n for n, _ in fitted[:k]])
        log["ensemble_val_mae_by_size"].append(fit.validation_mae(part, split))
    return MixedNarx(name, [n for n, _ in fitted]), log

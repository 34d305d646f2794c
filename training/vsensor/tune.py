"""``python -m training.vsensor tune``: one setting's PCA-NARX judged on the validation quarters.

What ``train`` fits first, and nothing else: the same files (cached replays), split,
standardisation, PCA and ``fit.fit_ensemble`` call with the same arguments, so a setting's
figure here is the PCA-NARX line ``train`` would print for it, without the baselines, the
export, the report or any held-out file (~half of ``train``'s time). Prints the closed-loop MAE
on the last 25 % of every file: overall, per file, over the grower's files (stem containing
``grower``) and the others (the controllers'), and over ``--subset`` stems (e.g. the files
of an earlier pass); ``--log FILE`` appends the summary as one JSON line. For an ensemble it
also scores the same members each fed its own past outputs (``own_feedback``: K loops averaged,
``fit.simulate_own_feedback``; ``--own-feedback`` makes it the figure, as train would).
``--holdout-groups``: leave one site x season out instead (training/vsensor/holdout_groups.py).
``--clamp-inputs``: also score the same fitted networks with every input clamped to the padded
training ranges (``VentSensor(clamp_inputs=True)``), paired: the ``clamped`` figures.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def add_tune_parser(sub: argparse._SubParsersAction, data_args) -> None:
    from training.vsensor.train_cli import add_fit_args

    p = sub.add_parser("tune", help="a setting's PCA-NARX on the validation quarters only",
                       description=__doc__.split("\n\n")[1].replace("\n", " "))
    data_args(p)
    add_fit_args(p)
    p.add_argument("--subset", nargs="+", default=[], metavar="STEM",
                   help="also report the MAE over these files' validation quarters")
    p.add_argument("--label", default="", help="a name for the setting in the log")
    p.add_argument("--log", metavar="FILE", help="append the summary as one JSON line")
    p.add_argument("--holdout-groups", nargs="*", default=None, metavar="GROUP",
                   help="leave one site x season out instead (training/vsensor/holdout_groups.py): "
                   "for each group (all, or the ones named) fit on the other groups' files and "
                   "score the whole held-out files")
    p.add_argument("--clamp-inputs", action="store_true",
                   help="also score the same networks with the inputs clamped to the padded "
                   "training ranges (paired; the 'clamped' figures)")
    p.set_defaults(func=run)


def groups(by_file: dict[str, dict], subset: list[str]) -> dict[str, float | None]:
    """MAE over the grower's files, the others, and ``subset`` (weighted by minutes)."""
    def mae(stems: list[str]) -> float | None:
        n = sum(by_file[s]["n"] for s in stems)
        return sum(by_file[s]["mae"] * by_file[s]["n"] for s in stems) / n if n else None

    from training.vsensor.holdout_groups import vents_of

    grower = [s for s in by_file if vents_of(s) == "grower"]
    out = {"grower": mae(grower), "controller": mae([s for s in by_file if s not in grower])}
    if subset:
        sub = [s for s in by_file if s in subset]
        out["subset"] = mae(sub)
        out["subset_grower"] = mae([s for s in sub if s in grower])
        out["subset_controller"] = mae([s for s in sub if s not in grower])
    return out


def run(args: argparse.Namespace) -> int:
    from threadpoolctl import threadpool_limits

    from gateway.cli.progress import progress_bar
    from gateway.greenhouse import load_greenhouse
    from training.vsensor import fit
    from training.vsensor.cli import overrides
    from training.vsensor.mixed import check_settings
    from training.vsensor.train import prepare, validation_metrics

    gh = load_greenhouse(args.greenhouse)
    hidden = tuple(int(v) for v in args.hidden.split(","))
    net_seed = args.seed if args.net_seed is None else args.net_seed
    seeds = [net_seed + j for j in range(args.ensemble)]
    check_settings(args.target, args.ensemble, args.feedback)
    if args.holdout_groups is not None:
        return run_groups(args, gh, hidden, seeds)
    t0 = time.perf_counter()
    # as train's bar: the files' replays, then one network's epochs and rounds (an upper bound)
    total = len(args.data) + len(seeds) * (args.epochs + min(30, args.epochs) * args.rounds)
    with threadpool_limits(1), progress_bar("tune", total, args.quiet) as bar:
        prep = prepare(args.data, gh, args.model, args.cache, overrides(args.set) or None,
                       args.seed, args.pca_variance, bar,
                       tuple(args.extra_features), args.target_kind)
        net, log = fit.fit_ensemble("pca_narx", prep.split, prep.mean, prep.std, prep.loadings,
                                    seeds, hidden, args.epochs, args.rounds, min(30, args.epochs),
                                    progress=bar, round_lr=args.round_lr,
                                    opts=fit.row_options(args.feedback_noise, args.high_flow_weight,
                                                         args.target, gh),
                                    feedback=args.feedback)
        net.own_feedback = args.own_feedback and len(seeds) > 1
        m, _ = validation_metrics(net, prep.split)
        own = (validation_metrics(net, prep.split, fit.simulate_own_feedback(net, prep.split))[0]
               if len(seeds) > 1 else None)
        clamped = (validation_metrics(net, prep.split, fit.simulate(net, prep.split,
                                                                    prep.input_bounds()))[0]
                   if args.clamp_inputs else None)
    summary = {"label": args.label, "components": int(prep.loadings.shape[1]),
               "variance": float(np.sum(prep.share[: prep.loadings.shape[1]])),
               "settings": _settings(args, net_seed),
               "mae": m["mae"], "mae_pct_range": m["mae_pct_range"], "range": m["range"],
               "by_file": {k: v["mae"] for k, v in m["by_file"].items()},
               "groups": groups(m["by_file"], args.subset),
               "own_feedback": None if own is None else
               {"mae": own["mae"], "by_file": {k: v["mae"] for k, v in own["by_file"].items()},
                "groups": groups(own["by_file"], args.subset)},
               "clamped": None if clamped is None else
               {"mae": clamped["mae"], "by_file": {k: v["mae"] for k, v in clamped["by_file"].items()},
                "groups": groups(clamped["by_file"], args.subset)},
               "members": log.get("member_val_mae"),
               "ensemble_by_size": log.get("ensemble_val_mae_by_size"),
               "rounds_log": log.get("ensemble_round_val_mae")
               or [lg["closed_loop_val_mae"] for lg in log.get("members", [log])],
               "seconds": round(time.perf_counter() - t0, 1)}
    print(json.dumps(summary, indent=1))
    _append(args.log, summary)
    return 0


def _settings(args: argparse.Namespace, net_seed: int) -> dict:
    return {k: getattr(args, k) for k in ("hidden", "epochs", "rounds", "round_lr", "pca_variance",
                                          "ensemble", "feedback", "feedback_noise",
                                          "high_flow_weight", "target", "extra_features",
                                          "own_feedback", "clamp_inputs")} | {"net_seed": net_seed}


def _append(log: str | None, summary: dict) -> None:
    if log:
        with Path(log).open("a", encoding="utf-8") as f:
            f.write(json.dumps(summary) + "\n")


def run_groups(args: argparse.Namespace, gh, hidden: tuple[int, ...], seeds: list[int]) -> int:
    """``--holdout-groups``: one fold per site x season group (holdout_groups.py)."""
    from threadpoolctl import threadpool_limits

    from training.vsensor import fit
    from training.vsensor import holdout_groups as hg
    from training.vsensor.cli import overrides
    from training.vsensor.train import prepare

    extra = tuple(args.extra_features)
    opts = fit.row_options(args.feedback_noise, args.high_flow_weight, args.target, gh)

    def fitter(split, mean, std, loadings):
        return fit.fit_ensemble("pca_narx", split, mean, std, loadings, seeds, hidden, args.epochs,
                                args.rounds, min(30, args.epochs), round_lr=args.round_lr,
                                opts=opts, feedback=args.feedback)[0]

    t0 = time.perf_counter()
    folds = []
    with threadpool_limits(1):
        segments = prepare(args.data, gh, args.model, args.cache, overrides(args.set) or None,
                           args.seed, args.pca_variance, lambda **k: None, extra,
                           args.target_kind).segments
        groups = hg.file_groups([Path(s.source).stem for s in segments])
        for g in args.holdout_groups or list(groups):
            if g not in groups:
                raise ValueError(f"--holdout-groups {g}: not one of {', '.join(groups)}")
            folds.append(hg.run_fold(g, segments, gh, args.model, args.seed, args.pca_variance,
                                     extra, fitter, args.clamp_inputs))
            f = folds[-1]
            print(f"fold {g}: {f.scores['all'].mae:.3f} m3 s-1 "
                  + (f"(own feedback {f.own['all'].mae:.3f}) " if f.own else "")
                  + (f"(inputs clamped {f.clamped['all'].mae:.3f}) " if f.clamped else "")
                  + f"in {f.seconds:.0f} s", flush=True)
            _append(args.log and f"{args.log}.folds", {"label": args.label, **hg.as_dict(f)})
    own = args.own_feedback and len(seeds) > 1
    print(hg.describe(folds, own))
    if args.clamp_inputs:
        print("\nthe same networks, inputs clamped to the padded training ranges:")
        print(hg.describe(folds, own, clamped=True))
    summary = {"label": args.label, "holdout_groups": True, "settings": _settings(args, seeds[0]),
               "headline": "own_feedback" if own else "ensemble",
               "summary": hg.summarise(folds), "own_feedback": hg.summarise(folds, True)
               if len(seeds) > 1 else None,
               "clamped": hg.summarise(folds, clamped=True) if args.clamp_inputs else None,
               "own_feedback_clamped": hg.summarise(folds, True, True)
               if args.clamp_inputs and len(seeds) > 1 else None,
               "folds": [hg.as_dict(f) for f in folds],
               "seconds": round(time.perf_counter() - t0, 1)}
    _append(args.log, summary)
    return 0

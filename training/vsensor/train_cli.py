"""``python -m training.vsensor train``: the sensor from kit CSVs, with a progress bar."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from gateway.cli.common import non_negative_int, positive_int, positive_number, seed_int


def add_train_parser(sub: argparse._SubParsersAction, data_args) -> None:
    p = sub.add_parser(
        "train", help="train the PCA-NARX sensor and its baselines, export ONNX + model card",
        description="Dataset (the adaptive model with and without the vent signal, cached), PCA "
        "(>= 90 % of the variance), NARX with input delays 0-5 and output delays 1-5, and the two "
        "baselines (same network without PCA, linear ARX); ONNX graphs with metadata, a model "
        "card and the training report beside them. Seeded: the same data give the same bytes.",
        epilog="example: python -m training.vsensor train --data out/vs/corpus/train/*.csv "
        "--greenhouse almeria-palmerillas --model almeria --out models/almeria.onnx",
    )
    data_args(p)
    p.add_argument("--out", required=True, metavar="MODEL.onnx", help="where to write the sensor")
    add_fit_args(p)
    p.add_argument("--test", nargs="+", default=[], metavar="FILE",
                   help="held-out kit CSVs scored after the fit (closed loop, the three models, as "
                   "python -m gateway vsensor does) into the model card and the summary; never "
                   "used by the fit")
    p.add_argument("--report", metavar="DIR",
                   help="where the report's PNGs go (default MODEL.report/ beside the model)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def add_fit_args(p: argparse.ArgumentParser) -> None:
    """The fit's settings, shared by ``train`` and ``tune`` (same defaults: same figure)."""
    p.add_argument("--hidden", default="30,50,20", metavar="N,N,N",
                   help="hidden layer sizes (default 30,50,20, the thesis's)")
    p.add_argument("--epochs", type=positive_int, default=100, metavar="N",
                   help="series-parallel epochs at most (default 100)")
    p.add_argument("--rounds", type=non_negative_int, default=6, metavar="N",
                   help="closed-loop refinement rounds, 0 or more (default 6)")
    p.add_argument("--round-lr", type=positive_number, default=None, metavar="LR",
                   help="Adam step size in the closed-loop rounds (default 1e-3, the "
                   "series-parallel one)")
    p.add_argument("--pca-variance", type=float, default=0.90, metavar="SHARE",
                   help="keep the fewest principal components reaching this share of the "
                   "variance (0.90 to 1; default 0.90)")
    p.add_argument("--ensemble", type=positive_int, default=1, metavar="K",
                   help="average K networks fitted from seeds NET_SEED … NET_SEED+K-1 inside each "
                   "NARX graph (PCA and no-PCA alike; default 1: one network)")
    p.add_argument("--net-seed", type=seed_int, default=None, metavar="N",
                   help="first seed of the networks (default --seed's, which also seeds the "
                   "estimator's replays; changing only this reuses the cached replays)")
    p.add_argument("--feedback", choices=("member", "ensemble"), default="member",
                   help="closed-loop rounds of an ensemble on each member's own feedback (default) "
                   "or on the ensemble's (what every member hears deployed)")
    p.add_argument("--feedback-noise", type=float, default=0.0, metavar="SIGMA",
                   help="a common N(0, SIGMA) offset, in units of the target's standard deviation, "
                   "on the five past outputs of every training row, redrawn each epoch (default 0)")
    p.add_argument("--high-flow-weight", type=positive_number, default=1.0, metavar="W",
                   help="loss weight of the training rows whose target is above the targets' 90th "
                   "percentile, the others 1 (default 1: unweighted)")
    # a metavar: the five choices in the usage line made it 86 columns wide
    p.add_argument("--target", choices=("identity", "sqrt", "log1p", "opening", "mixed"),
                   default="identity", metavar="KIND",
                   help="what the NARX networks learn and feed back: identity, the flow "
                   "(default identity); sqrt, its square root; log1p, log(1 + flow); opening, the "
                   "effective opening flow / D (D: the ventilation driver of III.31 from wind and "
                   "T_in - T_out); the graph inverts it (flows in, flow out). mixed: an "
                   "ensemble (--ensemble 2 or more) whose even network seeds learn the flow and "
                   "odd seeds the opening, each fitted as in a one-target ensemble, averaged as "
                   "flows in the graph")
    from gateway.vsensor.features import EXTRAS  # the one list of the derived inputs

    p.add_argument("--extra-features", nargs="+", default=[], metavar="NAME",
                   choices=tuple(EXTRAS),
                   help="derived inputs after the base ones (gateway.vsensor.features.EXTRAS; "
                   "default none); the runtime computes what the model's metadata names")
    p.add_argument("--own-feedback", action="store_true",
                   help="deployed, every member of an ensemble hears its own past outputs (K output "
                   "histories in the graph and the runtime) instead of the ensemble's mean")


def _check_outputs(out: str, report: str | None) -> None:
    """Refuse a sensor path that is a folder and a report folder that is a file before the
    training: both were refused after it, with the models already written."""
    from gateway.cli.common import check_output, no_stdout

    no_stdout(out, "--out")  # an ONNX graph, its card and report: files, not stdout
    if Path(out).is_dir():
        raise ValueError(f"--out {out}: is a folder; give the sensor's file name (MODEL.onnx)")
    check_output(report, "--report", folder=True)


def run(args: argparse.Namespace) -> int:
    from threadpoolctl import threadpool_limits

    from gateway.cli.progress import progress_bar
    from gateway.greenhouse import load_greenhouse
    from training.vsensor.cli import overrides
    from training.vsensor.train import train

    _check_outputs(args.out, args.report)
    gh = load_greenhouse(args.greenhouse)
    try:
        hidden = tuple(int(v) for v in args.hidden.split(","))
    except ValueError:
        raise ValueError(f"--hidden {args.hidden!r}: expected sizes like 30,50,20") from None
    total = len(args.data) + len(args.test) + 2 * args.ensemble * (args.epochs + 30 * args.rounds)
    t0 = time.perf_counter()
    with progress_bar("train", total, args.quiet) as bar, threadpool_limits(1):
        result = train(args.data, gh, args.model, args.out, args.cache, overrides(args.set) or None,
                       args.seed, hidden, args.epochs, args.rounds, progress=bar,
                       report_dir=args.report, round_lr=args.round_lr,
                       pca_variance=args.pca_variance, test_paths=args.test,
                       ensemble=args.ensemble, net_seed=args.net_seed, feedback=args.feedback,
                       feedback_noise=args.feedback_noise, high_flow_weight=args.high_flow_weight,
                       target=args.target, extra_features=tuple(args.extra_features),
                       own_feedback=args.own_feedback, target_kind=args.target_kind)
    summary = {"models": {k: str(v) for k, v in result.paths.items()}, "card": str(result.card),
               "pca": {k: v for k, v in result.pca.items() if k != "all_shares"},
               "validation_closed_loop": result.metrics,
               "ensemble": {k: {"member_val_mae": lg["member_val_mae"],
                                "ensemble_val_mae_by_size": lg["ensemble_val_mae_by_size"]}
                            for k, lg in result.logs.items() if "member_val_mae" in lg},
               "seconds": {k: round(v, 1) for k, v in result.seconds.items()},
               "held_out": {f: {n: {k: s[k] for k in ("flow", "q_vent", "flow_error_pct", "out_of_range")}
                                for n, s in per.items()} for f, per in result.heldout.items()}}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {', '.join(summary['models'].values())} and {result.card} "
              f"in {time.perf_counter() - t0:.0f} s")
        print(f"PCA: {result.pca['components']} components, "
              f"{100 * result.pca['variance_total']:.1f} % of the variance")
        for name, m in result.metrics.items():
            print(f"  {name:<12} closed-loop validation MAE {m['mae']:.3f} m3 s-1 "
                  f"({m['mae_pct_range']:.2f} % of range), R² {m['r2']:.3f}")
        by_file = result.metrics["pca_narx"]["by_file"]
        print("  pca_narx validation MAE by file: "
              + ", ".join(f"{k} {v['mae']:.3f}" for k, v in by_file.items() if v["mae"] is not None))
        for name, e in summary["ensemble"].items():
            print(f"  {name:<12} members' validation MAE "
                  f"{', '.join(f'{v:.3f}' for v in e['member_val_mae'])}; ensemble of the first "
                  f"1…K: {', '.join(f'{v:.3f}' for v in e['ensemble_val_mae_by_size'])}")
        for file, per in result.heldout.items():
            for name, s in per.items():
                f = s["flow"]
                print(f"  held out {file} {name:<12} MAE {f['mae']:.3f} m3 s-1 "
                      f"({f['mae_pct_range']:.2f} % of range), R² {f['r2']:.3f}")
    return 0

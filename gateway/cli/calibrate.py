"""``python -m gateway calibrate``: fit a model's parameters offline (thesis §III.4)."""

from __future__ import annotations

import argparse
import shlex
import sys

from gateway.cli import CliError
from gateway.cli.common import (
    add_data_arguments,
    add_sampling_argument,
    add_seed_argument,
    check_output,
    dump_json,
    load_run,
    parse_span,
    positive_int,
    write_params_file,
    writing,
)
from gateway.cli.notes import as_json, text_block
from gateway.cli.progress import progress_bar
from gateway.estimate.calibrate import calibrate, evaluate
from gateway.estimate.objective import MODES
from gateway.estimate.swarm import ALGORITHMS, make_algorithm


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="fit model parameters offline with RIWPSO, BA or RSBA",
        description="Fit the parameters of a climate model to measured data and report the "
        "error on the calibration span and on the rest of the data (validation).",
    )
    add_data_arguments(p)
    add_sampling_argument(p)
    p.add_argument("--algorithm", choices=ALGORITHMS, default="rsba", help="search algorithm (default rsba)")
    add_seed_argument(p, "the search")
    p.add_argument(
        "--calibrate-on",
        metavar="START/END",
        help="calibration span, e.g. 2009-10-21/2009-10-23 (default: all data, no validation)",
    )
    p.add_argument(
        "--cost", choices=MODES, default="one_step",
        help="error minimised: one-step-ahead (default) or free-run prediction",
    )
    p.add_argument("--iterations", type=positive_int, metavar="N",
                   help="iterations (default: the thesis's setting for the algorithm and model)")
    p.add_argument("--population", type=positive_int, metavar="N",
                   help="particles or bats (default: the thesis's setting for the algorithm and model)")
    p.add_argument("--out", metavar="params.toml", help="write the fitted parameters as TOML")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output(args.out, "--out", inputs={"--data": args.data, "--greenhouse": args.greenhouse})
    inputs = load_run(args)
    series, gh, model = inputs.series, inputs.gh, inputs.model
    span = parse_span(args.calibrate_on, series) or (0, len(series))
    algorithm = make_algorithm(args.algorithm, model.name, args.iterations, args.population)
    radiation = 1 if model.radiation is not None and "i_in" in series else 0  # one closed-form fit
    with progress_bar(f"{args.algorithm} {model.name}", algorithm.iterations + radiation, args.quiet) as bar:
        try:
            result = calibrate(
                model, series, gh, algorithm, span=span, mode=args.cost, seed=args.seed,
                progress=lambda stage, it, cost: bar(description=f"{stage}", info=f"MSE {cost:.3g}"),
            )
        except ValueError as exc:  # e.g. no calibration window without gaps
            raise CliError(f"{args.data}: {exc}") from None
    a, b = span
    validation = None
    rest = [(0, a), (b, len(series))]
    rest = [r for r in rest if r[1] - r[0] >= 2]
    if rest:
        # The longest held-out part is the validation span (free run starts at its first row).
        validation = evaluate(model, result.theta, series, gh, max(rest, key=lambda r: r[1] - r[0]))
    report = {
        "model": model.name,
        "algorithm": args.algorithm,
        "params": result.params,
        "metrics": {
            "calibration": evaluate(model, result.theta, series, gh, span),
            "validation": validation,
        },
        "seconds": result.seconds,
        "evaluations": result.evaluations,
        "cost": {"kind": args.cost, "mse": result.cost},
        "span": {"start": str(series.time[a]) + "Z", "end": str(series.time[b - 1]) + "Z"},
        "notes": as_json(inputs.notes),
    }
    if args.json:  # the report first: a failed write below still leaves the result on screen
        dump_json(report)
    else:
        _print_human(report)
        sys.stdout.write(text_block(inputs.notes))
    if args.out:
        with writing("--out", args.out):
            write_params_file(args.out, model, result.params, _command(args))
    return 0


def _command(args: argparse.Namespace) -> str:
    """The command that made the parameters file, whole (data, greenhouse, span, search), so
    its header can be run again to make the same file."""
    given = [("--data", args.data), ("--greenhouse", args.greenhouse), ("--model", args.model),
             ("--algorithm", args.algorithm), ("--seed", args.seed), ("--cost", args.cost),
             ("--sampling", args.sampling), ("--calibrate-on", args.calibrate_on),
             ("--step", args.step), ("--iterations", args.iterations),
             ("--population", args.population)]
    if args.site is not None:
        given.append(("--site", f"{args.site[0]:g},{args.site[1]:g}"))
    words = ["python", "-m", "gateway", "calibrate"]
    words += [w for option, value in given if value is not None for w in (option, f"{value:g}"
              if isinstance(value, float) else str(value))]
    return shlex.join(words)


def _print_human(report: dict) -> None:
    out = sys.stdout
    out.write(f"{report['model']} calibrated with {report['algorithm']} "
              f"in {report['seconds']:.1f} s ({report['evaluations']} evaluations)\n")
    for name, value in report["params"].items():
        out.write(f"  {name:<10} {value:.6g}\n")
    for part in ("calibration", "validation"):
        m = report["metrics"][part]
        if m is None:
            out.write(f"{part}: no data\n")
            continue
        for mode in ("one_step", "free_run", "persistence"):
            x = m.get(mode)
            if x:
                out.write(f"{part:>11} {mode:<11} MAE {x['mae']:.3f} °C  RMSE {x['rmse']:.3f}  "
                          f"MaxAE {x['maxae']:.3f}  R² {x['r2']:.4f}  EF {x['ef']:.4f}\n")

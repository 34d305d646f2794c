"""``python -m gateway replay``: run the online estimator over recorded data (thesis §IV.2)."""

from __future__ import annotations

import argparse
import sys

from gateway.cli import CliError
from gateway.cli.common import (
    add_data_arguments,
    add_seed_argument,
    check_figure,
    check_output,
    dump_json,
    load_run,
    read_params_file,
    writing,
)
from gateway.cli.notes import Note, as_json, echo, params_notes, text_block
from gateway.cli.progress import progress_bar
from gateway.estimate.online import online_settings
from gateway.estimate.outlook import OUTLOOKS, make_outlook
from gateway.estimate.replay import HORIZONS, replay, report, steps_of, write_predictions
from gateway.greenhouse import GreenhouseError, check_online_value
from gateway.model.params_file import outside_box

_KEYS = ("window", "every", "iterations", "bats", "prior")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="run the adaptive (online) model over recorded data, sample by sample",
        description="Feed a kit CSV to the online parameter estimator exactly as the live gateway "
        "would, and score its one-step-ahead prediction of the inside temperature against the "
        "same model with fixed parameters ('constant'), persistence and a recursive-least-squares "
        "linear baseline ('arx'), plus 15/30/60-minute forecasts with the weather later measured "
        "and with a causal weather outlook (what a live gateway can do), among them the model "
        "from its disturbance filter's state ('adaptive_kf') and that forecast combined with the "
        "ARX by recent skill ('combined', what the gateway publishes). Settings come from the "
        "model and the greenhouse's [online.<output>] tables (docs/online-estimator.md).",
        epilog="example: python -m gateway replay --data spring.csv --greenhouse almeria-palmerillas "
        "--model almeria --params calibrated.toml --json --plot replay.png",
    )
    add_data_arguments(p)
    p.add_argument(
        "--params", metavar="calibrated.toml",
        help="starting parameters written by 'calibrate --out' (default: the middle of each "
        "parameter's hard box, i.e. no offline calibration)",
    )
    p.add_argument(
        "--set", action="append", default=[], metavar="OUTPUT.KEY=VALUE",
        help="override an online setting, e.g. --set t_in.window=30 --set t_in.prior=1 "
        f"(keys: {', '.join(_KEYS)}); repeatable",
    )
    p.add_argument(
        "--warmup", type=float, default=0.0, metavar="MIN",
        help="leave the first MIN minutes out of every metric, e.g. 1440 to score days 2.. "
        "(default 0)",
    )
    add_seed_argument(p, "the bats")
    p.add_argument("--outlook", choices=sorted(OUTLOOKS),
                   help="weather outlook of the live-style forecasts (default: clear-sky-trend when "
                   "the greenhouse has a [site], else hold-latest)")
    p.add_argument("--out", metavar="predictions.csv",
                   help="write time, measured/predicted values, parameters and heat fluxes")
    p.add_argument("--plot", metavar="replay.png", help="draw measured vs predicted, residual, parameters")
    p.set_defaults(func=run)


def _overrides(items: list[str]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for item in items:
        try:
            key, value = item.split("=", 1)
            output, name = key.split(".", 1)
            number = float(value)
        except ValueError:
            raise CliError(f"--set {item!r}: expected OUTPUT.KEY=NUMBER, e.g. t_in.window=30") from None
        if name not in _KEYS:
            raise CliError(f"--set {item!r}: unknown key '{name}' (keys: {', '.join(_KEYS)})")
        try:  # the bounds a greenhouse file's [online.<output>] has
            number = check_online_value(f"--set {item!r}", output, name,
                                        int(number) if number.is_integer() else number)
        except GreenhouseError as exc:
            raise CliError(str(exc)) from None
        out.setdefault(output, {})[name] = number
    return out


def run(args: argparse.Namespace) -> int:
    sources = {"--data": args.data, "--greenhouse": args.greenhouse, "--params": args.params}
    check_output(args.out, "--out", inputs=sources)
    check_output(args.plot, "--plot", inputs=sources)
    check_figure(args.plot, "--plot")
    overrides = _overrides(args.set)  # a typo here is said before the data is read
    run_inputs = load_run(args)
    series, gh, model = run_inputs.series, run_inputs.gh, run_inputs.model
    theta0 = read_params_file(args.params, model, gh) if args.params else None
    notes = run_inputs.notes
    if theta0 is not None:
        made = params_notes(outside_box(theta0, model, gh), args.params,
                            "the estimator, and the 'constant' model, use")
        echo(made)
        notes = notes + made
    try:
        settings = online_settings(model, gh, overrides)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    made = _horizon_notes(series.step)
    echo(made)
    notes = notes + made
    if not args.warmup >= 0:  # also NaN
        raise CliError("--warmup must be >= 0 minutes")
    warmup = int(round(args.warmup * 60.0 / series.step))
    if warmup >= len(series) - 2:
        raise CliError(f"--warmup {args.warmup:g} min leaves no sample of {args.data} to score")
    outlook = None
    if args.outlook:
        try:
            outlook = make_outlook(args.outlook, gh)
        except ValueError as exc:
            hint = "; or give --site LAT,LON" if gh.site is None else ""
            raise CliError(f"{exc}{hint}") from None
    with progress_bar(f"replay {model.name}", len(series), args.quiet) as bar:
        result = replay(model, series, gh, theta0, settings, seed=args.seed,
                        progress=lambda done: bar(advance=100), outlook=outlook)
    rep = report(result, warmup)
    rep["data"] = args.data
    rep["start"] = "calibrated" if args.params else "middle of the hard box"
    rep["notes"] = as_json(notes)
    if args.json:  # the report first: a failed write below still leaves the result on screen
        dump_json(rep)
    else:
        _print_human(rep)
        sys.stdout.write(text_block(notes))
    if args.out:
        with writing("--out", args.out):
            write_predictions(result, args.out)
    if args.plot:
        from gateway.plots import plot_replay

        with writing("--plot", args.plot):
            plot_replay(result, args.plot, title=f"{model.name} on {args.data}")
    return 0


def _horizon_notes(step: float) -> list[Note]:
    """Say which of the report's horizons the model step cannot reach in whole steps."""
    left = [h for h in HORIZONS if h not in steps_of(HORIZONS, step)]
    if not left:
        return []
    return [Note("horizon_left_out", f"the {', '.join(map(str, left))}-minute forecast is left out: "
                 f"not a whole number of {step:g} s model steps")]


def _line(name: str, m: dict | None, unit: str = "°C") -> str:
    if not m:
        return f"  {name:<12} no comparable samples\n"
    return (f"  {name:<12} MAE {m['mae']:.3f} {unit}  RMSE {m['rmse']:.3f}  MaxAE {m['maxae']:.2f}  "
            f"R² {m['r2']:.4f}  EF {m['ef']:.4f}  (n={m['n']})\n")


def _print_human(rep: dict) -> None:
    out = sys.stdout
    out.write(f"{rep['model']} replay of {rep['data']}: {rep['samples']} samples, "
              f"{rep['skipped']} with dropped values, start: {rep['start']}\n")
    if rep["faults"]:
        out.write("  dropped: " + ", ".join(f"{k} {v}" for k, v in rep["faults"].items()) + "\n")
    out.write("one-step-ahead inside temperature:\n")
    for name, m in rep["metrics"].items():
        out.write(_line(name, m))
    for h, block in rep["horizons"].items():
        out.write(f"{h}-minute forecast, weather as later measured:\n")
        for name, m in block.items():
            if not name.endswith("_outlook"):
                out.write(_line(name, m))
        out.write(f"{h}-minute forecast, weather from the {rep['outlook']} outlook:\n")
        for name, m in block.items():
            if name.endswith("_outlook"):
                out.write(_line(name.removesuffix("_outlook"), m))
    if rep["radiation"]:
        out.write("inside radiation (sunlit samples):\n")
        for name, m in rep["radiation"].items():
            out.write(_line(name, m, "W m-2"))
    ms = rep["step_ms"]
    if ms["median"] is not None:
        out.write(f"time per step: median {ms['median']:.1f} ms, p95 {ms['p95']:.1f} ms, "
                  f"max {ms['max']:.1f} ms\n")

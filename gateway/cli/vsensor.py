"""``python -m gateway vsensor``: the virtual ventilation sensor over a kit CSV (thesis §IV.3)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from gateway.cli import CliError
from gateway.cli.column_notes import missing
from gateway.cli.common import (
    add_seed_argument,
    add_site_argument,
    check_output,
    dump_json,
    with_site,
    writing,
)
from gateway.cli.notes import as_json, echo, input_notes, text_block, vsensor_notes
from gateway.cli.progress import progress_bar
from gateway.greenhouse import GreenhouseError, list_presets, load_greenhouse
from gateway.kitcsv import KitCsvError
from gateway.model import MODEL_NAMES, build_model
from gateway.series import Series, TooCoarseError, load_series
from gateway.vsensor.features import MODEL_KINDS, columns_read

SHIPPED = "the model shipped for the kind (gateway/vsensor/models/<kind>.onnx)"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "vsensor",
        help="estimate the ventilation flow without a vent signal (PCA-NARX, ONNX)",
        description="Run the virtual ventilation sensor over a kit CSV: the adaptive model "
        "without the vent signal gives the heat fluxes, the PCA-NARX network turns them (with "
        "wind and the inside-outside differences) into the ventilation flow [m3 s-1] and heat "
        "loss [W m-2], closed loop, one step a minute, as the live gateway does. When the CSV "
        "carries vent openings, the run is scored against the explicit (vent-based) estimate, "
        "beside the baselines shipped with the model (the same network without PCA, a linear "
        "ARX). See docs/vsensor.md.",
        epilog="example: python -m gateway vsensor --data house.csv --greenhouse "
        "almeria-palmerillas --model-kind almeria --json --out flows.csv",
    )
    p.add_argument("--sensor", "--model", dest="sensor", metavar="MODEL.onnx",
                   help=f"the sensor's ONNX file, as 'python -m training.vsensor' names it; --model "
                   f"is the older name (default: {SHIPPED})")
    p.add_argument("--data", required=True, metavar="FILE", help="kit CSV (docs/data-format.md)")
    p.add_argument("--greenhouse", required=True, metavar="PRESET|FILE.toml",
                   help=f"greenhouse description: a preset ({', '.join(list_presets())}) or a TOML file")
    p.add_argument("--model-kind", required=True, choices=MODEL_KINDS,
                   help="the adaptive model whose fluxes feed the sensor")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_site_argument(p)
    p.add_argument("--out", metavar="flows.csv",
                   help="write time, flow, heat loss, out-of-range and valid flags per row")
    p.add_argument("--no-baselines", action="store_true", help="skip the baseline models")
    add_seed_argument(p, "the online estimator")
    p.add_argument("--clamp-inputs", action="store_true",
                   help="feed inputs outside the padded training ranges at their bound (still "
                   "flagged; off by default, docs/vsensor.md tenth pass)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gateway.vsensor.batch import replays_needed, run_series, score, write_flows
    from gateway.vsensor.model_info import ModelMismatch
    from gateway.vsensor.models import shipped_model
    from gateway.vsensor.runtime import VentSensor

    sensor_file(args.sensor)
    check_output(args.out, "--out", inputs={"--data": args.data, "--greenhouse": args.greenhouse,
                                            "--sensor": args.sensor})
    try:
        gh = with_site(load_greenhouse(args.greenhouse), args.site)
        model = build_model(args.model_kind, gh)
    except GreenhouseError as exc:
        raise CliError(str(exc)) from None
    try:
        series = load_series(args.data, step=60.0, required=model.requires)
    except TooCoarseError as exc:
        raise CliError(f"{args.data}: rows are {exc.native:g} s apart (median), and the "
                       f"virtual sensor runs on a {exc.step:g} s grid (it reads the minutes its "
                       "network was trained on): give rows at most 5 minutes apart") from None
    except KitCsvError as exc:
        raise CliError(str(exc)) from None
    try:
        path = args.sensor or shipped_model(args.model_kind)
    except FileNotFoundError as exc:
        raise CliError(str(exc)) from None
    try:
        sensor = VentSensor(path, gh, args.model_kind, clamp_inputs=args.clamp_inputs)
        reads = columns_read(args.model_kind, sensor.extra)
        check_columns(series, args.data, str(path), args.model_kind, reads, model.requires)
        notes = input_notes(series, gh, model, args.data, args.greenhouse, "vsensor", list(reads))
        echo(notes)
        replays = replays_needed(sensor, series, gh, args.model_kind)
        with progress_bar("vsensor", replays * len(series), args.quiet) as bar:
            result = run_series(path, series, gh, args.model_kind, seed=args.seed,
                                baselines=not args.no_baselines, clamp_inputs=args.clamp_inputs,
                                progress=lambda done: bar(advance=100), sensor=sensor)
    except (ModelMismatch, FileNotFoundError) as exc:
        raise CliError(str(exc)) from None
    made = vsensor_notes(result.notes)
    echo(made)
    notes += made
    sensors = score(result)
    main = next(iter(sensors))
    report = {
        "model": str(path), "data": args.data, "greenhouse": gh.name, "model_kind": args.model_kind,
        **sensors[main],
        "baselines": {k: v for k, v in sensors.items() if k != main},
        "reference": (f"explicit vent-based flow of the adaptive {result.reference_kind} model "
                      "(III.31)" if result.reference_kind else None),
        "notes": as_json(notes),
    }
    if args.json:  # the report first: a failed write below still leaves the result on screen
        dump_json(report)
    else:
        _print_human(report, main)
        sys.stdout.write(text_block(notes))
    if args.out:
        with writing("--out", args.out):
            write_flows(result, args.out)
    return 0


def check_columns(series: Series, data: str, sensor: str, kind: str,
                  reads: dict[str, tuple[str, ...]], requires: Sequence[str]) -> None:
    """Every column the sensor makes its inputs from (``reads``: column → inputs,
    ``features.columns_read``) and every column its ``kind`` model needs must hold values:
    without one, every minute would be flagged for a missing input. A column with values on
    some rows only is fine (its empty minutes are flagged). CliError naming the file, each
    column missing or empty and what reads it."""
    bad = []
    for col, inputs in reads.items():
        how = missing(series, col)
        if how:
            bad.append(f"{how} (the sensor's input{'s' * (len(inputs) > 1)} {', '.join(inputs)})")
    for col in requires:
        how = missing(series, col)
        if how and col not in reads:
            bad.append(f"{how} (the '{kind}' model's fluxes)")
    if bad:
        raise CliError(f"{data}: {'; '.join(bad)}: the virtual sensor {sensor} ({kind} kind) "
                       "cannot run without them; give the column(s) with values (cells left "
                       "empty here and there only flag their minutes)")


def sensor_file(path: str | None) -> None:
    """The sensor's file must exist; a model kind given in its place (``--model almeria``, as
    the other commands take it) is named as such instead of failing to load 'almeria' as ONNX."""
    from pathlib import Path

    if not path or Path(path).is_file():
        return
    if path in MODEL_NAMES and not Path(path).exists():
        raise CliError(f"--sensor/--model {path}: that is a model kind; here it goes in "
                       f"--model-kind {path}, and --sensor (or --model) names the sensor's "
                       f"ONNX file (default: {SHIPPED})")
    raise CliError(f"--sensor {path}: " + ("is a folder, not an ONNX file" if Path(path).is_dir()
                                           else "no such file"))


def _line(name: str, block: dict) -> str:
    f = block.get("flow")
    if not f:
        return f"  {name:<12} no reference flow\n"
    q = block["q_vent"]
    return (f"  {name:<12} flow MAE {f['mae']:.3f} m3 s-1 ({f['mae_pct_range']:.2f} % of range)  "
            f"RMSE {f['rmse']:.3f}  MaxAE {f['maxae']:.2f}  R² {f['r2']:.3f}   "
            f"heat loss MAE {q['mae']:.2f} W m-2\n")


def _print_human(rep: dict, main: str) -> None:
    out = sys.stdout
    out.write(f"{main} on {rep['data']} ({rep['greenhouse']}, {rep['model_kind']} fluxes): "
              f"{rep['steps']} steps, {rep['flagged']} flagged, {rep['out_of_range']} with inputs "
              f"outside the training ranges, {rep['missing']} with missing inputs, "
              f"{rep['clamped']} with the flow held to [0, its physical maximum]"
              + (f", {rep['inputs_clamped']} with inputs fed at their bound (--clamp-inputs)"
                 if rep.get("inputs_clamped") else "") + "\n")
    if rep["out_of_range_by_input"]:
        out.write("  outside the training range: "
                  + ", ".join(f"{k} {v}" for k, v in rep["out_of_range_by_input"].items()) + "\n")
    if rep["reference"]:
        out.write(f"closed loop vs the {rep['reference']}:\n")
        out.write(_line(main, rep))
        for name, block in rep["baselines"].items():
            out.write(_line(name, block))

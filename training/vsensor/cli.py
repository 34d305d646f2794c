"""``python -m training.vsensor corpus|dataset|train``: the virtual ventilation sensor, offline.

- ``corpus --out DIR``: generate the training and test kit CSVs (training/vsensor/corpus.py).
- ``dataset --data FILE... --greenhouse G --model KIND --cache DIR``: run the two replays of
  each file and cache their products (what ``train`` does first; run several in parallel).
- ``train --data FILE... --greenhouse G --model KIND --out MODEL.onnx``: train and export.
- ``tune --data FILE... [setting]``: one setting's PCA-NARX on the validation quarters only
  (what ``train`` fits first, nothing written; training/vsensor/tune.py).
- ``errors --sensor MODEL.onnx --data FILE...``: where a model's closed-loop validation error
  comes from (by file, wind, vents, hour, flow level, |ΔT|; training/vsensor/errors.py).
- ``score --sensor MODEL.onnx... --data FILE...``: written sensors side by side on held-out
  files (cached replays; the figures of ``python -m gateway vsensor``).
- ``reference --data FILE... --greenhouse G --model KIND``: the explicit flow (the target)
  beside the simulator's truth, and what its peaks are made of (training/vsensor/reference.py).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from gateway.cli import QUIET_HELP, CliError, after_the_command_too, setup_cli_logging
from gateway.cli.common import seed_int
from gateway.cli.helpformat import ArgumentParser
from gateway.greenhouse import GreenhouseError, list_presets, load_greenhouse
from gateway.kitcsv import KitCsvError
from gateway.vsensor.features import MODEL_KINDS

DEFAULT_CACHE = Path("out") / "vsensor-cache"


def _data_args(p: argparse.ArgumentParser, cache: bool = True) -> None:
    p.add_argument("--data", nargs="+", required=True, metavar="FILE",
                   help="kit CSVs with vent_roof/vent_side (docs/data-format.md)")
    p.add_argument("--greenhouse", required=True, metavar="PRESET|FILE.toml",
                   help=f"greenhouse description ({', '.join(list_presets())} or a TOML file)")
    p.add_argument("--model", required=True, choices=MODEL_KINDS,
                   help="the adaptive model whose fluxes the sensor reads")
    if cache:
        p.add_argument("--cache", default=str(DEFAULT_CACHE), metavar="DIR",
                       help=f"where the replays' products are kept (default {DEFAULT_CACHE})")
    p.add_argument("--set", action="append", default=[], metavar="OUTPUT.KEY=VALUE",
                   help="online estimator setting, e.g. --set t_in.bats=6 (default the "
                   "greenhouse's and the model's; recorded in the model)")
    p.add_argument("--seed", type=seed_int, default=0, metavar="N",
                   help="seed of the estimator and the network, 0 or more (default 0)")
    if not cache:  # the target option reads the cached replays
        return
    p.add_argument("--target-kind", choices=MODEL_KINDS, default=None, metavar="KIND",
                   help="the adaptive model whose replay with the vents gives the target flow "
                   "(default --model's; e.g. --model prototype --target-kind almeria: kit-only "
                   "inputs, the almeria model's flow, which needs t_soil in the training CSVs)")


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="python -m training.vsensor",
                            description="The PCA-NARX virtual ventilation sensor, offline "
                            "(thesis §IV.3). See docs/vsensor.md.")
    parser.add_argument("-q", "--quiet", action="store_true", help=QUIET_HELP)
    sub = parser.add_subparsers(dest="command", title="commands", metavar="COMMAND")
    c = sub.add_parser("corpus", help="generate the training and test kit CSVs",
                       description="Simulate the corpus's runs (training/vsensor/corpus.py) into "
                       "DIR/train, DIR/test, ...: each a kit CSV with its truth files. The whole "
                       "corpus takes minutes; --only picks runs.")
    c.add_argument("--out", required=True, metavar="DIR",
                   help="folder for the kit CSVs (train/, test/, ...) and their truth files")
    c.add_argument("--only", nargs="*", default=None, metavar="NAME",
                   help="only these runs (names as in training/vsensor/corpus.py)")
    c.add_argument("--hot-dry", action="store_true",
                   help="also the opt-in HOT_DRY runs (Sevilla, a third climate) in DIR/hot-dry")
    c.add_argument("--more-test", action="store_true",
                   help="also the opt-in MORE_TEST runs (more Biskra spring files) in DIR/more-test")
    c.set_defaults(func=_corpus)
    d = sub.add_parser("dataset", help="run the adaptive model with and without vents, cache",
                       description="Replay each file with and without its vent signal and keep "
                       "the products in --cache: what train, tune, errors and score do first "
                       "(one process per file can run in parallel).")
    _data_args(d)
    d.set_defaults(func=_dataset)
    from training.vsensor.train_cli import add_train_parser

    add_train_parser(sub, _data_args)
    from training.vsensor.tune import add_tune_parser

    add_tune_parser(sub, _data_args)
    r = sub.add_parser("reference", help="the explicit (vent-based) flow beside the simulator's "
                       "truth, and its peaks' conditions",
                       description="Replay each file with the vent signal, keeping the estimator's "
                       "parameters, and describe the explicit flow G (the training target): level "
                       "and spread beside the true flow (<stem>.truth.npz of the simulator), and "
                       "the wind, |T_in - T_out|, vents and vent coefficients at its peaks. It "
                       "replays each file afresh (it needs the estimator's parameters at every "
                       "minute, which the training cache does not keep).")
    _data_args(r, cache=False)
    r.add_argument("--above", type=float, default=30.0, metavar="M3_S",
                   help="a peak is a minute with G above this [m3 s-1] (default 30)")
    r.add_argument("--json", action="store_true", help="print the studies as JSON")
    r.set_defaults(func=_reference)
    e = sub.add_parser("errors", help="where a model's closed-loop validation error comes from",
                       description="Run MODEL in closed loop over the training files and split its "
                       "absolute flow error on their validation quarters (last 25 %) by file, wind, "
                       "vents, hour, explicit flow and |T_in - T_out|.")
    _data_args(e)
    e.add_argument("--sensor", dest="onnx", required=True, metavar="MODEL.onnx",
                   help="the written sensor to study (e.g. gateway/vsensor/models/almeria.onnx)")
    e.add_argument("--only", metavar="TEXT", help="the breakdowns over files whose name has TEXT")
    e.set_defaults(func=_errors)
    s = sub.add_parser("score", help="written sensors side by side on held-out files (cached)",
                       description="Run every MODEL in closed loop over each file (the gateway's "
                       "VentSensor, minute by minute, first hour left out) against the explicit flow "
                       "of the file's cached replays: the figures of python -m gateway vsensor and "
                       "of train --test, without replaying a file twice.")
    _data_args(s)
    s.add_argument("--sensor", dest="onnx", nargs="+", required=True, metavar="MODEL.onnx",
                   help="the written sensors to score")
    s.add_argument("--json", action="store_true", help="print the scores as JSON")
    s.add_argument("--clamp-inputs", action="store_true",
                   help="the sensors clamp their inputs to the padded training ranges")
    s.set_defaults(func=_score)
    after_the_command_too(parser, ("-q",))  # every command's -q, before or after it
    return parser


def _score(args: argparse.Namespace) -> int:
    import json

    from gateway.cli.progress import progress_bar
    from training.vsensor.dataset import build_segment
    from training.vsensor.heldout import score_segment, table

    _check_sensors(args.onnx)
    gh = load_greenhouse(args.greenhouse)
    models = {str(p): Path(p) for p in args.onnx}
    scores = {}
    # counted per file: its replays (cached: at once; else minutes, their rows as info), then
    # each sensor's minute-by-minute run
    with progress_bar("score", len(args.data) * (1 + len(models)), args.quiet) as bar:
        for p in args.data:
            bar(advance=0, description=Path(p).name)
            seg = build_segment(p, gh, args.model, args.cache, overrides(args.set) or None,
                                args.seed, progress=lambda done: bar(advance=0, info=f"row {done}"),
                                target_kind=args.target_kind)
            bar(advance=1, info="replays")
            scores[Path(p).stem] = score_segment(seg, models, gh, args.model, args.clamp_inputs,
                                                 progress=bar)
    if args.json:
        print(json.dumps({f: {m: {k: s[k] for k in ("flow", "q_vent", "flow_error_pct")}
                              for m, s in per.items()} for f, per in scores.items()}, indent=1))
    else:
        print(table(scores), end="")
    return 0


def _check_inputs(args: argparse.Namespace) -> None:
    """Name a missing held-out file, a cache that is a file, a log in a missing folder, a glob
    that matched nothing or a tune --subset stem of no file before the replays and the fit: a
    missing --test file was found after the training, the models written without their card.
    (A missing --data file is named by the first replay, at once.)"""
    from gateway.cli.common import check_output

    data = getattr(args, "data", None) or []  # corpus has none
    for path in data:
        if "*" in path and not Path(path).exists():  # the shell passes on a glob matching nothing
            raise ValueError(f"--data {path}: no such file (a pattern that matched nothing: an "
                             "empty or mistyped folder?)")
    unknown = set(getattr(args, "subset", None) or ()) - {Path(p).stem for p in data}
    if unknown:  # tune reported its MAE as null, after the fit
        raise ValueError(f"--subset {' '.join(sorted(unknown))}: no --data file has that stem")
    for path in getattr(args, "test", None) or ():
        _check_file(path, "--test", "a kit CSV")
    check_output(getattr(args, "cache", None), "--cache", folder=True)
    check_output(getattr(args, "log", None), "--log")  # tune appends to it after the fit


def _check_sensors(paths: list[str]) -> None:
    """Name a missing sensor before the replays (minutes for a file not yet cached), not after."""
    for path in paths:
        _check_file(path, "--sensor", "an ONNX file")


def _check_file(path: str, option: str, kind: str) -> None:
    if not Path(path).is_file():
        said = f"is a folder, not {kind}" if Path(path).is_dir() else "no such file"
        raise ValueError(f"{option} {path}: {said}")


def overrides(items: list[str]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for item in items:
        try:
            key, value = item.split("=", 1)
            output, name = key.split(".", 1)
            out.setdefault(output, {})[name] = float(value)
        except ValueError:  # main() prints it as one line, exit status 2
            raise ValueError(f"--set {item!r}: expected OUTPUT.KEY=NUMBER, e.g. t_in.bats=6") from None
    return out


def _corpus(args: argparse.Namespace) -> int:
    from training.vsensor.corpus import FRESH, HOT_DRY, MORE_TEST, OTHER, TEST, TRAIN, write_corpus

    every = (TRAIN + TEST + FRESH + OTHER + (HOT_DRY if args.hot_dry else ())
             + (MORE_TEST if args.more_test else ()))
    from gateway.cli.common import check_output

    check_output(args.out, "--out", folder=True)  # before a run's minutes, not after them
    unknown = sorted(set(args.only or ()) - {r.name for r in every})
    if unknown or args.only == []:  # a bare --only wrote nothing and said "0 runs"
        said = f"no run named {', '.join(unknown)}" if unknown else "name at least one run"
        raise ValueError(f"--only: {said} (runs: {', '.join(r.name for r in every)})")
    runs = tuple(r for r in every if args.only is None or r.name in args.only)
    from gateway.cli.progress import progress_bar

    t0 = time.perf_counter()
    with progress_bar("corpus", len(runs), args.quiet) as bar:
        paths = write_corpus(Path(args.out), runs, progress=bar)
    for path in paths:
        print(f"wrote {path}")
    print(f"{len(runs)} runs in {time.perf_counter() - t0:.1f} s")
    return 0


def _dataset(args: argparse.Namespace) -> int:
    from gateway.cli.progress import progress_bar
    from training.vsensor.dataset import build_segment

    gh = load_greenhouse(args.greenhouse)
    # counted in files; the replays' rows as info (piped: a line at least every 30 s of a file)
    with progress_bar("dataset", len(args.data), args.quiet) as bar:
        for path in args.data:
            t0 = time.perf_counter()
            bar(advance=0, description=Path(path).name)
            seg = build_segment(path, gh, args.model, args.cache, overrides(args.set), args.seed,
                                progress=lambda done: bar(advance=0, info=f"row {done}"),
                                target_kind=args.target_kind)
            bar(advance=1)
            print(f"{path}: {len(seg.time)} rows in {time.perf_counter() - t0:.0f} s", flush=True)
    return 0


def _reference(args: argparse.Namespace) -> int:
    import json

    from gateway.cli.progress import progress_bar
    from training.vsensor.reference import as_dict, describe, study

    gh = load_greenhouse(args.greenhouse)
    studies = []
    with progress_bar("reference", len(args.data), args.quiet) as bar:  # the replay's rows as info
        for p in args.data:
            bar(advance=0, description=Path(p).name)
            studies.append(study(p, gh, args.model, overrides(args.set) or None, args.seed,
                                 args.above, progress=lambda done: bar(advance=0, info=f"row {done}")))
            bar(advance=1)
    if args.json:
        print(json.dumps([as_dict(s) for s in studies], indent=1))
    else:
        print("\n".join(describe(s) for s in studies))
    return 0


def _errors(args: argparse.Namespace) -> int:
    from gateway.cli.progress import progress_bar
    from training.vsensor.errors import describe, study

    _check_sensors([args.onnx])
    if args.only is not None and not any(args.only in Path(p).stem for p in args.data):
        # found after the replays and the closed loops as numpy's "need at least one array"
        raise ValueError(f"--only {args.only!r}: in no --data file's name")
    gh = load_greenhouse(args.greenhouse)
    # the files' replays, then one closed loop over them all (errors.study)
    with progress_bar("errors", len(args.data) + 1, args.quiet) as bar:
        tables = study(args.onnx, args.data, gh, args.model, args.cache,
                       overrides(args.set) or None, args.seed, args.only, args.target_kind,
                       progress=bar)
    print(describe(tables))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_cli_logging(False)  # the CSV reader's notices as note: lines, as the gateway's
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        _check_inputs(args)
        return int(args.func(args) or 0)
    except (CliError, GreenhouseError, KitCsvError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file named on the command line: say which, not Python's repr
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2

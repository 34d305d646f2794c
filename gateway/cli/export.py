"""``python -m gateway export``: a device's stored minutes as a kit CSV for the other tools."""

from __future__ import annotations

import argparse
import sqlite3
import sys
from pathlib import Path

from gateway.cli import CliError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="write a device's stored minute aggregates as a kit CSV (for calibrate, replay, ...)",
        description="Write the minute aggregates the ingest service stored for one device as a "
        "kit CSV (docs/data-format.md). Values the QC flagged as missing, spikes or a stuck "
        "sensor are left empty and counted; minutes never received stay out (a gap).",
        epilog="example: python -m gateway export --db serra.db --from 2026-03-01T00:00Z "
        "--out march.csv && python -m gateway diagnose --data march.csv --greenhouse "
        "biskra-prototype --model prototype",
    )
    p.add_argument("--db", required=True, type=Path, metavar="serra.db",
                   help="the ingest service's SQLite store")
    p.add_argument("--out", required=True, type=Path, metavar="FILE.csv",
                   help="kit CSV to write; - writes it on stdout (what it wrote then goes to stderr)")
    p.add_argument("--device", type=int, metavar="ID",
                   help="device id (default: the only one in the store)")
    p.add_argument("--from", dest="start", metavar="ISO",
                   help="first minute, e.g. 2026-03-01 or 2026-03-01T06:00 (UTC unless an offset "
                   "is given, as in calibrate --calibrate-on)")
    p.add_argument("--to", dest="end", metavar="ISO", help="end of the span (excluded)")
    p.add_argument("--json", action="store_true", help="print what was written as one JSON object")
    p.set_defaults(func=run)


def _when(text: str | None, flag: str) -> float | None:
    if text is None:
        return None
    from gateway.cli.common import parse_when

    try:
        return float(parse_when(text).astype("int64"))
    except ValueError as exc:  # the parser's own words only when they say more
        why = ("not an ISO 8601 date or time, e.g. 2026-03-01 or 2026-03-01T06:00Z"
               if str(exc).startswith("Invalid isoformat") else str(exc))
        raise CliError(f"{flag}: bad time {text!r}: {why}") from None


def run(args: argparse.Namespace) -> int:
    from gateway.cli.common import dump_json
    from gateway.store import StoreError, open_readonly
    from gateway.store.export import ExportError, export_kit_csv

    start, end = _when(args.start, "--from"), _when(args.end, "--to")
    if start is not None and end is not None and end <= start:
        raise CliError(f"--to {args.end}: not after --from {args.start}")
    to_stdout = str(args.out) == "-"
    if to_stdout and args.json:
        raise CliError("--out - with --json: the CSV and the JSON would share stdout; give --out "
                       "a file name, or leave out --json")
    if args.out.is_dir():
        raise CliError(f"--out {args.out}: is a folder; give the kit CSV's file name")
    if args.out.exists() and args.db.exists() and args.out.samefile(args.db):
        raise CliError(f"--out {args.out}: is the store --db; writing the CSV would replace it")
    try:  # a reader: never creates, converts or writes the file it reads
        conn = open_readonly(args.db)
    except StoreError as exc:
        raise CliError(str(exc)) from None
    try:
        done = export_kit_csv(conn, sys.stdout if to_stdout else args.out, args.device, start, end)
    except ExportError as exc:
        raise CliError(f"{args.db}: {exc}") from None
    except sqlite3.Error as exc:
        raise CliError(f"{args.db}: {exc}") from None
    except OSError as exc:  # writing the CSV (the store was opened above)
        raise CliError(f"--out {args.out}: cannot write: {exc.strerror or exc}") from None
    finally:
        conn.close()
    if args.json:
        dump_json({"device": done.device_id, "rows": done.rows, "start": done.start,
                   "end": done.end, "dropped": done.dropped, "aggregated": done.aggregated,
                   "out": str(args.out)})
        return 0
    print(f"wrote {'the CSV on stdout' if to_stdout else args.out}: device {done.device_id}, "
          f"{done.rows} minutes, {done.start} → {done.end}", file=sys.stderr if to_stdout else sys.stdout)
    print("  each row is the mean over its minute: calibrate reads such rows with --sampling mean "
          "(docs/data-format.md)", file=sys.stderr)
    for name, reasons in done.dropped.items():
        text = ", ".join(f"{n} {why}" for why, n in reasons.items())
        print(f"  {name}: left empty: {text}", file=sys.stderr)
    return 0

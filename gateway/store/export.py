"""Store → kit CSV: one device's minute aggregates, as the tools read them (docs/data-format.md).

Values the minute QC flagged as missing, a spike or a stuck sensor become empty cells (counted
per channel and reason), never made-up numbers; a minute with some missing samples
(``partial``) keeps the mean of the valid ones. Minutes with no row at all stay absent: the
tools treat the hole as a gap. Samples stored after the ingest service's last aggregation pass
are aggregated in memory (`aggregate.pending_minutes`), so an export never silently misses the
newest data and never writes: it reads through `open_readonly`.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np

from gateway.kitcsv import write_kit_csv
from gateway.protocol import CHANNELS
from gateway.store.aggregate import QC_MISSING, QC_NAMES, QC_SPIKE, QC_STUCK, pending_minutes

DROP = QC_MISSING | QC_SPIKE | QC_STUCK
"""QC flags whose value is left out of the export."""


class ExportError(ValueError):
    """The export cannot be made as asked (no such device, nothing in the span, ...)."""


@dataclass
class Export:
    """What an export wrote: rows, span and the values left empty per channel and reason."""

    device_id: int
    rows: int
    start: str | None
    end: str | None
    dropped: dict[str, dict[str, int]] = field(default_factory=dict)
    aggregated: int = 0  # minutes computed from samples not yet aggregated by the service


def pick_device(conn: sqlite3.Connection, device_id: int | None) -> int:
    """The device to export: the one asked for, or the only one in the store."""
    known = [r[0] for r in conn.execute("SELECT device_id FROM devices ORDER BY device_id")]
    if device_id is not None:
        if device_id not in known:
            raise ExportError(f"no device {device_id} in the store (devices: "
                              f"{', '.join(map(str, known)) or 'none'})")
        return device_id
    if len(known) != 1:
        raise ExportError(
            "the store holds no device yet" if not known else
            f"the store holds {len(known)} devices ({', '.join(map(str, known))}): pick one "
            "with --device")
    return known[0]


def export_kit_csv(
    conn: sqlite3.Connection,
    out: str | Path | TextIO,
    device_id: int | None = None,
    start: float | None = None,
    end: float | None = None,
    catch_up: bool = True,
) -> Export:
    """Write the minute aggregates of a device in [start, end) [unix s] as a kit CSV at ``out`` (a path
    or an open text stream).

    Reads only (``conn`` may come from `open_readonly`); with ``catch_up`` the samples stored
    since the last aggregation pass are aggregated in memory and take their minutes' place."""
    dev = pick_device(conn, device_id)
    lo, hi = -np.inf if start is None else start, np.inf if end is None else end
    cols = ", ".join(f"{c}, {c}_qc" for c in CHANNELS)
    by_minute = {r[0]: r for r in conn.execute(
        f"SELECT minute, {cols} FROM minute WHERE device_id=? AND minute>=? AND minute<?",
        (dev, lo, hi))}
    newer = pending_minutes(conn, dev) if catch_up else {}
    by_minute.update((m, (m, *r[3:])) for m, r in newer.items() if lo <= m < hi)
    aggregated = len(newer)
    rows = [by_minute[m] for m in sorted(by_minute)]
    if not rows:
        raise ExportError(f"device {dev}: no minute in the span asked for")
    table = np.array([[np.nan if v is None else v for v in r] for r in rows], dtype=float)
    time = table[:, 0].astype(np.int64).astype("datetime64[s]")
    columns: dict[str, np.ndarray] = {}
    dropped: dict[str, dict[str, int]] = {}
    for i, name in enumerate(CHANNELS):
        values, flags = table[:, 1 + 2 * i], table[:, 2 + 2 * i].astype(int)
        for bit in (QC_MISSING, QC_SPIKE, QC_STUCK):
            # each value counted once, under its first reason
            hit = int(np.count_nonzero(((flags & bit) != 0) & ((flags & (bit - 1) & DROP) == 0)))
            if hit:
                dropped.setdefault(name, {})[QC_NAMES[bit]] = hit
        values = np.where(flags & DROP, np.nan, values)
        if name == "rain":  # kit CSV: 0/1; a minute with any wet reading is wet
            values = np.where(np.isfinite(values), (values > 0).astype(float), np.nan)
        columns[name] = values
    write_kit_csv(out, time, columns)
    return Export(dev, len(rows), str(time[0]) + "Z", str(time[-1]) + "Z", dropped, aggregated)

"""Minute aggregates with QC flags, computed incrementally from newly stored samples.

Late samples (resends after an outage) mark their minute for recomputation, so a minute row is
always the aggregate of everything stored for it.
"""

from __future__ import annotations

import sqlite3

from gateway.protocol import CHANNELS, ST_PARTIAL
from gateway.store.db import transaction

QC_MISSING = 1  # no valid sample in the minute
QC_PARTIAL = 2  # some samples of the minute were missing or partial on this channel
QC_SPIKE = 4  # step from the previous minute larger than physically plausible
QC_STUCK = 8  # identical value for STUCK_MINUTES minutes in a row (a frozen sensor)
QC_NAMES = {QC_MISSING: "missing", QC_PARTIAL: "partial", QC_SPIKE: "spike", QC_STUCK: "stuck"}

MAX_STEP = {"t_in": 5.0, "rh_in": 25.0, "t_out": 5.0, "rh_out": 25.0, "i_glob": 1200.0,
            "wind": 30.0}
STUCK_MINUTES = 30
STUCK_CHANNELS = ("t_in", "rh_in", "t_out", "rh_out")

_SEL = ", ".join(f"{c}, {c}_st" for c in CHANNELS)
_MIN_COLS = ["device_id", "minute", "n"] + [x for c in CHANNELS for x in (c, f"{c}_qc")]
_UPSERT = (f"INSERT OR REPLACE INTO minute ({', '.join(_MIN_COLS)}) "
           f"VALUES ({', '.join('?' * len(_MIN_COLS))})")


Overlay = dict[int, list]
"""Minute rows computed but not written (minute -> row as _minute_row returns it)."""


def _earlier(conn: sqlite3.Connection, overlay: Overlay | None, dev: int, i: int, lo: int,
             hi: int) -> list:
    """Channel i's minute means for minutes in [lo, hi): the table's, or the overlay's."""
    name = CHANNELS[i]
    got = dict(conn.execute(
        f"SELECT minute, {name} FROM minute WHERE device_id=? AND minute>=? AND minute<?",
        (dev, lo, hi)).fetchall())
    if overlay:
        got.update((m, r[3 + 2 * i]) for m, r in overlay.items() if lo <= m < hi)
    return list(got.values())


def _minute_row(conn: sqlite3.Connection, dev: int, minute: int,
                overlay: Overlay | None = None) -> list:
    rows = conn.execute(f"SELECT {_SEL} FROM samples WHERE device_id=? AND t>=? AND t<?",
                        (dev, minute, minute + 60)).fetchall()
    out: list = [dev, minute, len(rows)]
    for i, name in enumerate(CHANNELS):
        vals = [r[2 * i] for r in rows if r[2 * i] is not None]
        flags = 0
        if not vals:
            flags |= QC_MISSING
        if any(r[2 * i + 1] >= ST_PARTIAL for r in rows):
            flags |= QC_PARTIAL
        mean = sum(vals) / len(vals) if vals else None
        if mean is not None and name in MAX_STEP:
            prev = _earlier(conn, overlay, dev, i, minute - 60, minute)
            if prev and prev[0] is not None and abs(mean - prev[0]) > MAX_STEP[name]:
                flags |= QC_SPIKE
        if mean is not None and name in STUCK_CHANNELS:
            hist = _earlier(conn, overlay, dev, i, minute - 60 * (STUCK_MINUTES - 1), minute)
            if len(hist) == STUCK_MINUTES - 1 and all(h == mean for h in hist):
                flags |= QC_STUCK
        out += (mean, flags)
    return out


def _last_aggregated(conn: sqlite3.Connection) -> int:
    return int((conn.execute("SELECT value FROM meta WHERE name='agg_rowid'").fetchone()
                or ("0",))[0])


def pending_minutes(conn: sqlite3.Connection, dev: int) -> Overlay:
    """The minute rows `aggregate` would write for a device, computed without writing: what a
    read-only reader adds to the `minute` table so it never misses the newest samples."""
    touched = [r[0] for r in conn.execute(
        "SELECT DISTINCT CAST(t / 60 AS INTEGER) * 60 AS m FROM samples "
        "WHERE rowid>? AND device_id=? ORDER BY m", (_last_aggregated(conn), dev))]
    overlay: Overlay = {}
    for minute in touched:  # in time order: a minute's QC sees the minutes computed before it
        overlay[minute] = _minute_row(conn, dev, minute, overlay)
    return overlay


def _span(conn: sqlite3.Connection, max_rows: int) -> tuple[int, int]:
    last = _last_aggregated(conn)
    top = conn.execute("SELECT max(rowid) FROM samples").fetchone()[0] or 0
    return last, min(top, last + max_rows)


def aggregate(conn: sqlite3.Connection, max_rows: int = 20_000) -> int:
    """Recompute the minutes touched by samples stored since the last call; returns how many.

    At most `max_rows` new samples per call, so a backlog never holds the write lock for long
    (the ingest writer, and so the acknowledgements, wait meanwhile). Safe to call from two
    connections at once (the ingest service and the live gateway): the span is read again
    under the write lock."""
    last, top = _span(conn, max_rows)
    if top <= last:
        return 0
    with transaction(conn):
        last, top = _span(conn, max_rows)
        touched = sorted(conn.execute(
            "SELECT DISTINCT device_id, CAST(t / 60 AS INTEGER) * 60 FROM samples "
            "WHERE rowid>? AND rowid<=?", (last, top)).fetchall(), key=lambda r: (r[0], r[1]))
        for dev, minute in touched:
            conn.execute(_UPSERT, _minute_row(conn, dev, minute))
        conn.execute("INSERT OR REPLACE INTO meta (name, value) VALUES ('agg_rowid', ?)",
                     (str(top),))
    return len(touched)

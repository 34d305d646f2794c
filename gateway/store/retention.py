"""Retention (configurable ages) and capacity alarms, so the SD card never fills silently."""

from __future__ import annotations

import os
import shutil
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

from gateway.store.capacity import Alarm, CapacityWatch, cleared_lines

MIN_DAYS = 1.0
"""Shortest age [d] a table may be kept for: less would delete samples before the day's
diagnosis has read them (the ingest command line and the gateway config both check it)."""
MIN_DB_MB = 1.0
"""Smallest database size alarm [MiB] accepted."""


@dataclass(frozen=True)
class Policy:
    samples_days: float = 400.0
    minute_days: float = 3650.0
    estimates_days: float = 3650.0
    outbox_sent_days: float = 2.0
    max_db_bytes: int = 4 << 30  # alarm at alarm_fraction of this
    min_free_bytes: int = 256 << 20
    alarm_fraction: float = 0.8


def _delete_older(conn: sqlite3.Connection, table: str, col: str, before: float) -> int:
    # Small transactions: the ingest writer never waits long for the lock.
    total = 0
    while True:
        n = conn.execute(f"DELETE FROM {table} WHERE rowid IN (SELECT rowid FROM {table} "
                         f"WHERE {col} < ? LIMIT 5000)", (before,)).rowcount
        total += n
        if n < 5000:
            return total


def apply(conn: sqlite3.Connection, policy: Policy, now: float | None = None) -> dict[str, int]:
    now = time.time() if now is None else now
    day = 86400.0
    cut = now - policy.estimates_days * day
    out = {
        "samples": _delete_older(conn, "samples", "t", now - policy.samples_days * day),
        # records acknowledged as rejected are kept as long as the records stored: without a
        # cut a kit rejecting a record a minute would grow the table for as long as it runs
        "rejected": _delete_older(conn, "rejected", "t_recv", now - policy.samples_days * day),
        "minute": _delete_older(conn, "minute", "minute", now - policy.minute_days * day),
        "estimates": _delete_older(conn, "estimates", "t", cut),
        "outbox": _delete_older(conn, "outbox", "sent", now - policy.outbox_sent_days * day),
    }
    # A newest row older than the cut is the last of its name: its rows above are gone too.
    conn.execute("DELETE FROM estimates_latest WHERE t < ?", (cut,))
    return out


def measure(db_path: str | Path, policy: Policy) -> list[Alarm]:
    """The store's capacity alarms now; empty when it has room."""
    db_path = Path(db_path)
    size = sum(os.path.getsize(p) for p in (db_path, Path(f"{db_path}-wal")) if p.exists())
    alarms = []
    if size >= policy.alarm_fraction * policy.max_db_bytes:
        alarms.append(Alarm("size", size / policy.max_db_bytes,
                            f"database {db_path} is {size / 1e6:.0f} MB, "
                            f"{100 * size / policy.max_db_bytes:.0f} % of its limit: shorten "
                            "retention"))
    free = shutil.disk_usage(db_path.parent).free
    if free < policy.min_free_bytes:
        alarms.append(Alarm("free", free, f"only {free / 1e6:.0f} MB free on the disk of {db_path}"))
    return alarms


def capacity_alarms(db_path: str | Path, policy: Policy) -> list[str]:
    """Human-readable alarms; empty when the store has room (said in the log by a
    :class:`CapacityWatch`, not here: the maintenance measures every 10 s)."""
    return [a.text for a in measure(db_path, policy)]


def watch_capacity(watch: CapacityWatch, db_path: str | Path, policy: Policy) -> None:
    """A maintenance round's measure, said by ``watch`` (start, reminder, worse, cleared)."""
    watch.check(measure(db_path, policy), cleared_lines(
        Path(db_path), policy.max_db_bytes, policy.alarm_fraction, policy.min_free_bytes))

"""Connection setup and the batching sample writer."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

from gateway.protocol import CHANNELS, Record
from gateway.store import schema


def open_db(path: str | Path, *, durable: bool = True) -> sqlite3.Connection:
    """Open (and create) the store. WAL + synchronous=FULL: a commit survives a power cut."""
    conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False,
                           timeout=30)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute(f"PRAGMA synchronous={'FULL' if durable else 'NORMAL'}")
    conn.execute("PRAGMA busy_timeout=30000")
    schema.create(conn)
    return conn


_COLS = ["device_id", "boot", "seq", "t", "t_recv", "tick_ms", "period_s"]
for _c in CHANNELS:
    _COLS += [_c, f"{_c}_st"]
_INSERT = (f"INSERT OR IGNORE INTO samples ({', '.join(_COLS)}) "
           f"VALUES ({', '.join('?' * len(_COLS))})")
_UPSERT_DEVICE = """
INSERT INTO devices (device_id, boot, max_seq, first_seen, last_seen, n_samples)
VALUES (?, ?, ?, ?, ?, ?)
ON CONFLICT(device_id) DO UPDATE SET
  max_seq = CASE WHEN excluded.boot > boot THEN excluded.max_seq
                 WHEN excluded.boot = boot THEN max(max_seq, excluded.max_seq)
                 ELSE max_seq END,
  boot = max(boot, excluded.boot),
  last_seen = max(last_seen, excluded.last_seen),
  n_samples = n_samples + excluded.n_samples
"""


@contextmanager
def transaction(conn: sqlite3.Connection, mode: str = "IMMEDIATE") -> Iterator[None]:
    conn.execute(f"BEGIN {mode}")
    try:
        yield
    except BaseException:
        conn.execute("ROLLBACK")
        raise
    conn.execute("COMMIT")


class DeviceState(NamedTuple):
    boot: int
    max_seq: int


class Store:
    """The gateway's store: one connection, used from one thread at a time."""

    def __init__(self, path: str | Path, *, durable: bool = True) -> None:
        self.path = Path(path)
        self.conn = open_db(path, durable=durable)

    def close(self) -> None:
        self.conn.close()

    def write_batch(self, items: Sequence[tuple[Record, float]]) -> int:
        """Store (record, t_recv) pairs in one transaction; durable when this returns.

        One commit per batch: fewer fsyncs, fewer SD-card page writes.
        """
        if not items:
            return 0
        rows = []
        dev: dict[int, list] = {}  # device -> [boot, max_seq, first_seen, last_seen, n]
        for rec, t_recv in items:
            v, st = rec.values, rec.status
            rows.append((rec.device_id, rec.boot, rec.seq, t_recv - rec.age_ms / 1000.0, t_recv,
                         rec.tick_ms, rec.period_s, v[0], st[0], v[1], st[1], v[2], st[2],
                         v[3], st[3], v[4], st[4], v[5], st[5], v[6], st[6]))
            d = dev.get(rec.device_id)
            if d is None:
                dev[rec.device_id] = [rec.boot, rec.seq, t_recv, t_recv, 1]
                continue
            if rec.boot > d[0] or (rec.boot == d[0] and rec.seq > d[1]):
                d[0], d[1] = rec.boot, rec.seq
            if t_recv > d[3]:
                d[3] = t_recv
            d[4] += 1
        c = self.conn
        with transaction(c):
            before = c.total_changes
            c.executemany(_INSERT, rows)
            stored = c.total_changes - before
            c.executemany(_UPSERT_DEVICE, [(k, *d) for k, d in dev.items()])
        return stored

    def device_states(self) -> dict[int, DeviceState]:
        return {d: DeviceState(b, s) for d, b, s in
                self.conn.execute("SELECT device_id, boot, max_seq FROM devices")}

    def stored_seqs(self, device_id: int, boot: int, above: int) -> set[int]:
        cur = self.conn.execute(
            "SELECT seq FROM samples WHERE device_id=? AND boot=? AND seq>?",
            (device_id, boot, above))
        return {r[0] for r in cur}

    def integrity_ok(self) -> bool:
        return self.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"

    def get_meta(self, name: str, default: str | None = None) -> str | None:
        r = self.conn.execute("SELECT value FROM meta WHERE name=?", (name,)).fetchone()
        return r[0] if r else default

    def set_meta(self, name: str, value: str) -> None:
        self.conn.execute("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)",
                          (name, value))

    # Estimates: written by the online estimator / virtual sensor, read by tools.
    def add_estimates(self, rows: Iterable[tuple[float, str, str, float | None, str]]) -> None:
        """rows: (t, source, name, value, unit)."""
        with transaction(self.conn):
            self.conn.executemany(
                "INSERT INTO estimates (t, source, name, value, unit) VALUES (?, ?, ?, ?, ?)",
                rows)

    def estimates(self, name: str, since: float = 0.0) -> list[tuple[float, str, float | None]]:
        return list(self.conn.execute(
            "SELECT t, source, value FROM estimates WHERE name=? AND t>=? ORDER BY t",
            (name, since)))

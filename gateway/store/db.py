"""Connection setup (the writer's and the readers'), the batching sample writer."""

from __future__ import annotations

import os
import re
import sqlite3
import urllib.parse
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import NamedTuple

from gateway.protocol import CHANNELS, BoardHealth, Record
from gateway.store import losses, schema


class StoreError(RuntimeError):
    """A file that cannot serve as the store, named with the reason (one line for the user)."""


class StoreGone(StoreError):
    """The store's file was deleted or replaced while open: SQLite writes on into a file no one
    will open again, so what it commits is lost when the process ends."""


# The tables every Serra store has had since schema version 1: a file without them is not ours.
SERRA_TABLES = frozenset({"samples", "devices", "minute", "meta"})
_OURS = frozenset(re.findall(r"CREATE TABLE IF NOT EXISTS (\w+)",
                             schema.DDL_V1 + schema.DDL_V2_TABLES + schema.DDL_V3_TABLES
                             + schema.DDL_V4_TABLES + schema.DDL_V5_LATEST)) | {
    "sqlite_sequence"}  # SQLite's own, for AUTOINCREMENT


def _tables(conn: sqlite3.Connection) -> set[str]:
    return {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}


def open_db(path: str | Path, *, durable: bool = True) -> sqlite3.Connection:
    """Open (and create) the store, for the one writer. WAL + synchronous=FULL: a commit
    survives a power cut. A new file is created 0600 (SQLite gives its -wal and -shm the same
    mode); another program's database is refused before anything is written to it."""
    path = Path(path)
    try:  # owner-only from the first byte, whatever the umask
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    except FileExistsError:
        pass
    except OSError as e:
        raise StoreError(f"{path}: cannot open the store: {(e.strerror or str(e)).lower()}"
                         ) from None
    conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False,
                           timeout=30)
    try:
        foreign = _tables(conn) - _OURS
        if conn.execute("PRAGMA user_version").fetchone()[0] == 0 and foreign:
            raise StoreError(f"{path}: a database of another program (tables "
                             f"{', '.join(sorted(foreign))}), not a Serra store; give a new file")
    except BaseException:
        conn.close()
        raise
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute(f"PRAGMA synchronous={'FULL' if durable else 'NORMAL'}")
    conn.execute("PRAGMA busy_timeout=30000")
    schema.create(conn)
    return conn


def close_db(conn: sqlite3.Connection, wait_s: float = 2.0) -> None:
    """Close a writer's connection cleanly: the WAL is first copied into the database and
    truncated to zero bytes (``PRAGMA wal_checkpoint(TRUNCATE)``). SQLite does so by itself only
    when the *last* connection to close is a writer's; with a reader still open (the history
    queryable, the status screen) a clean stop left the -wal beside the store at its full size
    (~4 MB). A reader in a transaction is waited for at most ``wait_s`` [s]; a checkpoint still
    blocked then is partial, and the next start finishes it."""
    with suppress(sqlite3.Error):  # a connection that failed: closing it is all that is left
        if not conn.in_transaction:
            conn.execute(f"PRAGMA busy_timeout={int(wait_s * 1000)}")
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
    conn.close()


def open_readonly(path: str | Path) -> sqlite3.Connection:
    """Open a Serra store for reading only (export, the status screen, any tool that reads).

    The connection cannot write (SQLite ``mode=ro``): no table, journal mode, schema version or
    aggregate is ever written by a reader. Raises StoreError, naming the file, for a missing
    file, an empty file, a file that is not SQLite, another program's database, or a store of a
    newer schema than this gateway knows. Readers of a live store see every committed batch.
    """
    path = Path(path)
    if not path.exists():
        raise StoreError(f"{path}: no such store")
    if not path.is_file():
        raise StoreError(f"{path}: not a file")
    if not os.access(path, os.R_OK):
        raise StoreError(f"{path}: permission denied (the store is readable by its owner only: "
                         "run this as that user, e.g. sudo -u serra ...)")
    if path.stat().st_size == 0:
        raise StoreError(f"{path}: empty file, not a Serra store")
    uri = f"file:{urllib.parse.quote(str(path.resolve()))}?mode=ro"
    try:
        conn = sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False,
                               timeout=30)
    except sqlite3.Error as e:
        raise StoreError(f"{path}: cannot open the store: {e}") from None
    try:
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        tables = _tables(conn)
        missing = SERRA_TABLES - tables
    except sqlite3.DatabaseError as e:
        conn.close()
        if "not a database" in str(e):
            raise StoreError(f"{path}: not an SQLite database, not a Serra store") from None
        # e.g. a WAL store in a directory this user may not write, with no -shm file yet
        raise StoreError(f"{path}: cannot read the store: {e}") from None
    if version == 0 or missing:
        conn.close()
        cloud = (" (a cloud store, which 'python -m gateway subscribe --db ... --export DIR' "
                 "reads)" if "messages" in tables and missing == SERRA_TABLES else "")
        raise StoreError(f"{path}: not a Serra store (schema version {version}; missing tables "
                         f"{', '.join(sorted(missing)) or 'none'}){cloud}")
    if version > schema.SCHEMA_VERSION:
        conn.close()
        raise StoreError(f"{path}: store schema version {version} is newer than this gateway's "
                         f"({schema.SCHEMA_VERSION}); update the gateway")
    conn.execute("PRAGMA busy_timeout=30000")
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
    try:
        conn.execute("COMMIT")
    except BaseException:
        # SQLite may leave the transaction open when COMMIT fails (SQLITE_BUSY always, an I/O
        # error sometimes): roll it back, or every later BEGIN fails ("cannot start a
        # transaction within a transaction") and the write lock stays held until a restart.
        if conn.in_transaction:
            with suppress(sqlite3.Error):
                conn.execute("ROLLBACK")
        raise


class DeviceState(NamedTuple):
    boot: int
    max_seq: int


class Store:
    """The gateway's store: one connection, used from one thread at a time."""

    def __init__(self, path: str | Path, *, durable: bool = True) -> None:
        self.path = Path(path)
        self.conn = open_db(path, durable=durable)
        self._ident = self._identity()

    def _identity(self) -> tuple[int, int] | None:
        try:
            st = os.stat(self.path)
        except OSError:
            return None
        return st.st_dev, st.st_ino

    def check_file(self) -> None:
        """Raise StoreGone when the file at ``path`` is no longer the one opened (deleted, its
        folder removed, or replaced): call after a commit, before anything is acknowledged."""
        if self._identity() != self._ident:
            raise StoreGone(f"{self.path}: the store file was deleted or replaced while open")

    def close(self) -> None:
        close_db(self.conn)

    def write_batch(self, items: Sequence[tuple[Record, float]],
                    report: losses.Report | None = None) -> int:
        """Store (record, t_recv) pairs in one transaction; durable when this returns.

        One commit per batch: fewer fsyncs, fewer SD-card page writes. The records the boards
        lost that this batch makes final are counted in the same transaction (gateway/store/
        losses.py), reported in ``report``.
        """
        if not items:
            return 0
        rows = []
        seen: dict[int, dict[int, losses.BootBatch]] = {}
        dev: dict[int, list] = {}  # device -> [boot, max_seq, first_seen, last_seen, n]
        for rec, t_recv in items:
            v, st = rec.values, rec.status
            rows.append((rec.device_id, rec.boot, rec.seq, t_recv - rec.age_ms / 1000.0, t_recv,
                         rec.tick_ms, rec.period_s, v[0], st[0], v[1], st[1], v[2], st[2],
                         v[3], st[3], v[4], st[4], v[5], st[5], v[6], st[6]))
            b = seen.setdefault(rec.device_id, {}).get(rec.boot)
            if b is None:
                b = seen[rec.device_id][rec.boot] = losses.BootBatch([], round(rec.period_s * 10))
            b.seqs.append(rec.seq)
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
            found = losses.Report()
            losses.account(c, seen, found)
            before = c.total_changes
            c.executemany(_INSERT, rows)
            stored = c.total_changes - before
            c.executemany(_UPSERT_DEVICE, [(k, *d) for k, d in dev.items()])
        if report is not None:
            report.gaps += found.gaps
            report.lost += found.lost
        return stored

    def note_rejected(self, device_id: int, boot: int, seq: int, reason: str,
                      t_recv: float) -> losses.Report:
        """Keep a record acknowledged as rejected (boot as stored): the board drops it, so it
        is not a loss."""
        report = losses.Report()
        with transaction(self.conn):
            losses.note_rejected(self.conn, device_id, boot, seq, reason, t_recv, report)
        return report

    def note_health(self, h: BoardHealth, boot: int, t_recv: float) -> None:
        """Keep a device's latest health packet (boot as stored), replacing the one before."""
        with transaction(self.conn):
            self.conn.execute(
                "INSERT OR REPLACE INTO board_health (device_id, boot, hseq, t_recv, uptime_s, "
                "records, dropped_full, dropped_old, sent, acked, rejected, send_errors, "
                "heap_free, ring, rssi_dbm) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (h.device_id, boot, h.hseq, t_recv, h.uptime_s, h.records, h.dropped_full,
                 h.dropped_old, h.sent, h.acked, h.rejected, h.send_errors, h.heap_free, h.ring,
                 h.rssi_dbm))

    def health_states(self) -> dict[int, tuple[int, int, int]]:
        """device → (boot as stored, hseq, records dropped) of its latest health packet."""
        return {r[0]: (r[1], r[2], r[3] + r[4]) for r in self.conn.execute(
            "SELECT device_id, boot, hseq, dropped_full, dropped_old FROM board_health")}

    def device_states(self) -> dict[int, DeviceState]:
        return {d: DeviceState(b, s) for d, b, s in
                self.conn.execute("SELECT device_id, boot, max_seq FROM devices")}

    def boot_base(self, device_id: int, key_id: str) -> int:
        """The offset added to the boots a device sends under the key `key_id`.

        0 for the first key of a device (and for the key of a device seen before keys were
        recorded); for a new key, one above the latest boot stored, fixed when the key is first
        met and kept in `meta`. A board reflashed with a new key may so restart its boot counter
        at 0 without colliding with its stored rows, while the old key's packets stay replays.
        """
        name = f"boot_base/{device_id}/{key_id}"
        with transaction(self.conn):
            got = self.get_meta(name)
            if got is not None:
                return int(got)
            known = self.conn.execute("SELECT count(*) FROM meta WHERE name LIKE ?",
                                      (f"boot_base/{device_id}/%",)).fetchone()[0]
            row = self.conn.execute("SELECT boot FROM devices WHERE device_id=?",
                                    (device_id,)).fetchone()
            base = 0 if row is None or not known else row[0] + 1
            self.set_meta(name, str(base))
        return base

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

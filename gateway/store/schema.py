"""SQLite schema (version in PRAGMA user_version). Documented in docs/store.md.

Version 5 keys the estimates by time: one index ``estimates_tgn`` (t, greenhouse, name, value)
instead of ``estimates_t`` (t) and ``estimates_gh`` (greenhouse, name, t), so a minute's rows are
appended together at the index's right edge (``estimates_gh`` put a greenhouse-minute's 16 rows
on 16 leaf pages: 20.7 of the 24.2 WAL pages a greenhouse-minute the estimate rows cost; 5.4
now), and the table ``estimates_latest``, kept by a trigger, holds each name's newest row, which
the status screen's "latest of a name" reads: :func:`migrate_v4_v5`
(tests/bench/estimates_layout.py, docs/store.md "Migration from version 4").

Version 4 adds ``board_health``: the latest health packet of each device, the counters its board
reports itself (docs/wire-format.md, "Health packet"): :func:`migrate_v3_v4`, one table.

Version 3 adds ``boot_losses`` (records a board dropped before they were stored, per device and
boot, and how far that is settled) and ``rejected`` (records acknowledged as rejected, which are
not losses): :func:`migrate_v2_v3`, tables only.

Version 2 (the live gateway) adds the greenhouse to ``estimates``; kind, observation time and
idempotency key to ``outbox`` (which is also the log the history queryable answers from); and the
tables ``greenhouses``, ``estimator_state``, ``findings`` and ``gateway_status``. A version-1
file is migrated in place, in one transaction, keeping every row (:func:`migrate_v1_v2`).
New columns are appended, so a migrated file and a new one have the same tables.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager

from gateway.protocol import CHANNELS

SCHEMA_VERSION = 5

_chan_cols = ",\n".join(f"  {c} REAL,\n  {c}_st INTEGER NOT NULL" for c in CHANNELS)
_qc_cols = ",\n".join(f"  {c} REAL,\n  {c}_qc INTEGER NOT NULL" for c in CHANNELS)

DDL_V1 = f"""
CREATE TABLE IF NOT EXISTS devices (
  device_id INTEGER PRIMARY KEY,
  boot INTEGER NOT NULL,          -- latest boot counter seen (older boots are replays)
  max_seq INTEGER NOT NULL,       -- highest sequence number stored for that boot
  first_seen REAL NOT NULL,
  last_seen REAL NOT NULL,
  n_samples INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS samples (
  device_id INTEGER NOT NULL,
  boot INTEGER NOT NULL,
  seq INTEGER NOT NULL,
  t REAL NOT NULL,                -- wall time assigned by the gateway: t_recv - age [unix s]
  t_recv REAL NOT NULL,
  tick_ms INTEGER NOT NULL,       -- device monotonic clock at the end of the period
  period_s REAL NOT NULL,
{_chan_cols},
  PRIMARY KEY (device_id, boot, seq)
);
CREATE INDEX IF NOT EXISTS samples_t ON samples(t);
CREATE TABLE IF NOT EXISTS minute (
  device_id INTEGER NOT NULL,
  minute INTEGER NOT NULL,        -- start of the minute [unix s]
  n INTEGER NOT NULL,             -- samples whose time falls in the minute
{_qc_cols},
  PRIMARY KEY (device_id, minute)
);
CREATE TABLE IF NOT EXISTS estimates (
  id INTEGER PRIMARY KEY,
  t REAL NOT NULL,
  source TEXT NOT NULL,           -- e.g. "online", "vsensor"
  name TEXT NOT NULL,             -- parameter or variable name (shared vocabulary)
  value REAL,
  unit TEXT NOT NULL DEFAULT '',
  info TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS estimates_t ON estimates(t);
CREATE TABLE IF NOT EXISTS outbox (
  id INTEGER PRIMARY KEY AUTOINCREMENT,
  created REAL NOT NULL,
  key TEXT NOT NULL,              -- publish key expression
  payload TEXT NOT NULL,
  attempts INTEGER NOT NULL DEFAULT 0,
  sent REAL                       -- NULL until the publisher confirms
);
CREATE INDEX IF NOT EXISTS outbox_pending ON outbox(sent, id);
CREATE TABLE IF NOT EXISTS meta (
  name TEXT PRIMARY KEY,
  value TEXT NOT NULL
);
"""
"""Version 1, frozen: what a version-1 gateway created (the migration starts from it)."""

_V2_COLUMNS = (
    ("estimates", "greenhouse", "TEXT NOT NULL DEFAULT ''"),  # '' = not tied to a greenhouse
    ("outbox", "kind", "TEXT NOT NULL DEFAULT ''"),  # e.g. measurement/inside, forecast
    ("outbox", "t", "REAL"),  # observation time of the message [unix s, gateway clock]
    ("outbox", "idem", "TEXT"),  # idempotency key, unique; the cloud drops repeats by it
)

DDL_V2_TABLES = """
CREATE INDEX IF NOT EXISTS estimates_gh ON estimates(greenhouse, name, t);
CREATE UNIQUE INDEX IF NOT EXISTS outbox_idem ON outbox(idem);
CREATE INDEX IF NOT EXISTS outbox_key_t ON outbox(key, t);
CREATE TABLE IF NOT EXISTS greenhouses (
  name TEXT PRIMARY KEY,          -- greenhouse name in the gateway config and the key space
  farm TEXT NOT NULL,
  inside_device INTEGER NOT NULL,
  outside_device INTEGER NOT NULL,
  model TEXT NOT NULL,
  config TEXT NOT NULL,           -- JSON: the greenhouse's resolved config section
  updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS estimator_state (
  greenhouse TEXT PRIMARY KEY,
  model TEXT NOT NULL,
  minute INTEGER NOT NULL,        -- last minute stepped [unix s]
  state TEXT NOT NULL,            -- JSON snapshot of the online estimator
  updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS findings (
  id TEXT PRIMARY KEY,            -- stable identity: effect@greenhouse@start of first detection
  greenhouse TEXT NOT NULL,
  effect TEXT NOT NULL,
  start REAL,                     -- start of the effect [unix s], NULL: before the data
  first_seen REAL NOT NULL,
  last_seen REAL NOT NULL,
  revision INTEGER NOT NULL,      -- bumped when the finding changes
  published_revision INTEGER NOT NULL DEFAULT 0,
  detail TEXT NOT NULL            -- JSON: the diagnosis's finding (params, summary, evidence)
);
CREATE TABLE IF NOT EXISTS gateway_status (
  name TEXT PRIMARY KEY,          -- gateway, zenoh, outbox, ingest, devices, ...
  value TEXT NOT NULL,            -- JSON
  updated REAL NOT NULL           -- gateway clock [unix s]
);
"""


def _columns(conn: sqlite3.Connection, table: str) -> list[str]:
    return [r[1] for r in conn.execute(f"PRAGMA table_info({table})")]


@contextmanager
def _migration(conn: sqlite3.Connection, version: int) -> Iterator[None]:
    """One migration step in one transaction that ends at ``version``: all of it or nothing."""
    conn.execute("BEGIN IMMEDIATE")
    try:
        yield
        conn.execute(f"PRAGMA user_version = {version}")
    except BaseException:
        conn.execute("ROLLBACK")
        raise
    conn.execute("COMMIT")


def migrate_v1_v2(conn: sqlite3.Connection) -> None:
    """Version 1 → 2 in one transaction: columns appended, v1 outbox rows get the idempotency
    key ``v1:<id>``; no row is changed otherwise, none is removed."""
    with _migration(conn, 2):
        for table, col, decl in _V2_COLUMNS:
            if col not in _columns(conn, table):
                conn.execute(f"ALTER TABLE {table} ADD COLUMN {col} {decl}")
        conn.execute("UPDATE outbox SET idem = 'v1:' || id WHERE idem IS NULL")
        for stmt in DDL_V2_TABLES.split(";"):
            if stmt.strip():
                conn.execute(stmt)


DDL_V3_TABLES = """
CREATE TABLE IF NOT EXISTS boot_losses (
  device_id INTEGER NOT NULL,
  boot INTEGER NOT NULL,          -- as stored (board counter + its key's boot base)
  final_seq INTEGER NOT NULL,     -- every seq below is settled: stored, rejected or lost
  lost INTEGER NOT NULL DEFAULT 0,  -- seqs below final_seq neither stored nor rejected
  open_from INTEGER,              -- first seq of a lost run reaching final_seq - 1 (not logged)
  PRIMARY KEY (device_id, boot)
);
CREATE TABLE IF NOT EXISTS rejected (
  device_id INTEGER NOT NULL,
  boot INTEGER NOT NULL,
  seq INTEGER NOT NULL,
  reason TEXT NOT NULL,           -- malformed, out_of_range (acked as rejected: not resent)
  t_recv REAL NOT NULL,
  PRIMARY KEY (device_id, boot, seq)
);
"""


def migrate_v2_v3(conn: sqlite3.Connection) -> None:
    """Version 2 → 3 in one transaction: the loss tables. Each device's latest boot is settled
    up to its oldest stored seq (what came before may have gone to retention, or to a store
    this one replaced: not counted); earlier boots are not counted."""
    with _migration(conn, 3):
        for stmt in DDL_V3_TABLES.split(";"):
            if stmt.strip():
                conn.execute(stmt)
        conn.execute(
            "INSERT OR IGNORE INTO boot_losses (device_id, boot, final_seq, lost) "
            "SELECT d.device_id, d.boot, coalesce((SELECT min(seq) FROM samples s WHERE "
            "s.device_id = d.device_id AND s.boot = d.boot), 0), 0 FROM devices d")


DDL_V4_TABLES = """
CREATE TABLE IF NOT EXISTS board_health (
  device_id INTEGER PRIMARY KEY,
  boot INTEGER NOT NULL,          -- as stored: the board's counter plus its key's boot base
  hseq INTEGER NOT NULL,          -- health packet number in that boot (the replay check)
  t_recv REAL NOT NULL,           -- gateway clock [unix s]
  uptime_s INTEGER NOT NULL,
  records INTEGER NOT NULL,       -- records made this boot
  dropped_full INTEGER NOT NULL,  -- dropped from the board's ring: full
  dropped_old INTEGER NOT NULL,   -- dropped from the board's ring: too old (seq span, 2**28 ms)
  sent INTEGER NOT NULL,          -- transmissions, resends included
  acked INTEGER NOT NULL,
  rejected INTEGER NOT NULL,
  send_errors INTEGER NOT NULL,
  heap_free INTEGER NOT NULL,     -- bytes
  ring INTEGER NOT NULL,          -- records waiting in the ring
  rssi_dbm INTEGER                -- NULL: unknown (UART, or the port has none)
)
"""


def migrate_v3_v4(conn: sqlite3.Connection) -> None:
    """Version 3 → 4 in one transaction: the health table, empty (filled by the next packets)."""
    with _migration(conn, 4):
        conn.execute(DDL_V4_TABLES)


# value: the status screen's day series read the index alone (without it 3-4x slower than v4's
# estimates_gh; with it < 2x, tests/bench/estimates_layout.py)
DDL_V5_INDEX = ("CREATE INDEX IF NOT EXISTS estimates_tgn ON estimates(t, greenhouse, name, "
                "value)")
DDL_V5_LATEST = """
CREATE TABLE IF NOT EXISTS estimates_latest (
  greenhouse TEXT NOT NULL,
  name TEXT NOT NULL,
  source TEXT NOT NULL,
  t REAL NOT NULL,                -- the newest row of (greenhouse, name, source) in estimates
  value REAL,
  unit TEXT NOT NULL,
  info TEXT NOT NULL,
  PRIMARY KEY (greenhouse, name, source)
) WITHOUT ROWID"""
# SQLite's bare columns beside max(t) come from the row holding the max.
V5_FILL_LATEST = ("INSERT OR REPLACE INTO estimates_latest (greenhouse, name, source, t, value, "
                  "unit, info) SELECT greenhouse, name, source, max(t), value, unit, info "
                  "FROM estimates GROUP BY greenhouse, name, source")
DDL_V5_TRIGGER = """
CREATE TRIGGER IF NOT EXISTS estimates_latest_upsert AFTER INSERT ON estimates BEGIN
  INSERT INTO estimates_latest (greenhouse, name, source, t, value, unit, info)
  VALUES (NEW.greenhouse, NEW.name, NEW.source, NEW.t, NEW.value, NEW.unit, NEW.info)
  ON CONFLICT (greenhouse, name, source) DO UPDATE SET
    t = excluded.t, value = excluded.value, unit = excluded.unit, info = excluded.info
  WHERE excluded.t >= estimates_latest.t;
END"""
"""Every estimate row inserted, by whatever writer, keeps ``estimates_latest`` (a row older than
the one kept leaves it); retention prunes both with one cut (:mod:`gateway.store.retention`)."""


def migrate_v4_v5(conn: sqlite3.Connection) -> None:
    """Version 4 → 5 in one transaction: ``estimates_latest`` filled from ``estimates``, its two
    indexes replaced by ``estimates_tgn``. No row of another table is touched; the dropped
    indexes' pages go to the free list, which the file's growth reuses."""
    with _migration(conn, 5):
        conn.execute(DDL_V5_LATEST)
        conn.execute(V5_FILL_LATEST)
        conn.execute(DDL_V5_TRIGGER)
        conn.execute("DROP INDEX IF EXISTS estimates_gh")
        conn.execute("DROP INDEX IF EXISTS estimates_t")
        conn.execute(DDL_V5_INDEX)


def create(conn: sqlite3.Connection) -> None:
    """Create the tables of a new store or migrate a version-1 store; a current one is left as
    it is. A new file is made the same way as a migrated one (version 1, then the migration), so
    the two cannot differ."""
    ver = conn.execute("PRAGMA user_version").fetchone()[0]
    if ver not in (0, 1, 2, 3, 4, SCHEMA_VERSION):
        raise RuntimeError(f"database schema version {ver}, this gateway knows {SCHEMA_VERSION}")
    if ver < 2:
        conn.executescript(DDL_V1)  # IF NOT EXISTS: nothing happens to a version-1 file
        migrate_v1_v2(conn)
    if ver < 3:
        migrate_v2_v3(conn)
    if ver < 4:
        migrate_v3_v4(conn)
    if ver < SCHEMA_VERSION:
        migrate_v4_v5(conn)

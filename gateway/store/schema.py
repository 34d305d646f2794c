"""SQLite schema (version in PRAGMA user_version). Documented in docs/wire-format.md."""

from __future__ import annotations

import sqlite3

from gateway.protocol import CHANNELS

SCHEMA_VERSION = 1

_chan_cols = ",\n".join(f"  {c} REAL,\n  {c}_st INTEGER NOT NULL" for c in CHANNELS)
_qc_cols = ",\n".join(f"  {c} REAL,\n  {c}_qc INTEGER NOT NULL" for c in CHANNELS)

DDL = f"""
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


def create(conn: sqlite3.Connection) -> None:
    ver = conn.execute("PRAGMA user_version").fetchone()[0]
    if ver not in (0, SCHEMA_VERSION):
        raise RuntimeError(f"database schema version {ver}, this gateway knows {SCHEMA_VERSION}")
    conn.executescript(DDL)
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

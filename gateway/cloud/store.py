"""The cloud side's store: every message received, once, by idempotency key.

:class:`CloudStore` is the interface the subscriber writes through; :class:`SqliteCloudStore` is
the embedded default. A PostgreSQL store (its own issue) implements the same four methods with
``INSERT ... ON CONFLICT (idem) DO NOTHING`` and the same columns.

Table ``messages``: ``seq`` (arrival order of first receipt), ``idem`` (unique), ``key``,
``farm``, ``greenhouse``, ``kind``, ``t`` (observation time from the payload [unix s]),
``payload`` (the JSON as received), ``received`` (wall time [unix s]).
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Protocol

from gateway.publish import keyspace as K

TIME_ATTRS = ("dateObserved", "dateIssued", "dateModified")


@dataclass(frozen=True)
class Received:
    """One message as it arrived: key, payload and what the store indexes it by."""

    key: str
    payload: str
    idem: str
    farm: str
    greenhouse: str
    kind: str
    t: float | None
    received: float


class NotAMessage(ValueError):
    """A sample that is not a Serra message (not JSON, no idempotency key, foreign key)."""


def parse(key: str, payload: str | bytes, received: float | None = None) -> Received:
    """A received sample → :class:`Received` (raises :class:`NotAMessage`)."""
    try:
        farm, greenhouse, kind = K.split(key)
        text = payload.decode() if isinstance(payload, bytes) else payload
        doc = json.loads(text)
        idem = doc["idempotencyKey"]["value"]
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
        raise NotAMessage(f"{key}: {e}") from None
    t = None
    for name in TIME_ATTRS:
        v = doc.get(name, {}).get("value") if isinstance(doc.get(name), dict) else None
        if isinstance(v, dict) and "@value" in v:
            t = datetime.fromisoformat(v["@value"]).timestamp()
            break
    return Received(key, text, str(idem), farm, greenhouse, kind, t,
                    time.time() if received is None else received)


class CloudStore(Protocol):
    def add(self, messages: Sequence[Received]) -> int:
        """Store the messages not seen before (by idempotency key); returns how many were new."""
        ...

    def count(self) -> int: ...

    def messages(self, farm: str | None = None, greenhouse: str | None = None,
                 kind: str | None = None) -> Iterator[Received]:
        """Stored messages in arrival order (first receipt)."""
        ...

    def close(self) -> None: ...


class SqliteCloudStore:
    DDL = """
    CREATE TABLE IF NOT EXISTS messages (
      seq INTEGER PRIMARY KEY AUTOINCREMENT,
      idem TEXT NOT NULL UNIQUE,
      key TEXT NOT NULL,
      farm TEXT NOT NULL,
      greenhouse TEXT NOT NULL,
      kind TEXT NOT NULL,
      t REAL,
      payload TEXT NOT NULL,
      received REAL NOT NULL
    );
    CREATE INDEX IF NOT EXISTS messages_where ON messages(farm, greenhouse, kind, t);
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False,
                                    timeout=30)
        self.conn.execute("PRAGMA journal_mode=WAL")
        self.conn.execute("PRAGMA synchronous=FULL")
        self.conn.executescript(self.DDL)

    def add(self, messages: Sequence[Received]) -> int:
        if not messages:
            return 0
        c = self.conn
        c.execute("BEGIN IMMEDIATE")
        try:
            before = c.total_changes
            c.executemany(
                "INSERT OR IGNORE INTO messages (idem, key, farm, greenhouse, kind, t, payload, "
                "received) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [(m.idem, m.key, m.farm, m.greenhouse, m.kind, m.t, m.payload, m.received)
                 for m in messages])
            new = c.total_changes - before
        except BaseException:
            c.execute("ROLLBACK")
            raise
        c.execute("COMMIT")
        return new

    def count(self) -> int:
        return self.conn.execute("SELECT count(*) FROM messages").fetchone()[0]

    def messages(self, farm: str | None = None, greenhouse: str | None = None,
                 kind: str | None = None) -> Iterator[Received]:
        where, args = [], []
        for col, v in (("farm", farm), ("greenhouse", greenhouse), ("kind", kind)):
            if v is not None:
                where.append(f"{col}=?")
                args.append(v)
        sql = ("SELECT key, payload, idem, farm, greenhouse, kind, t, received FROM messages"
               + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY seq")
        for r in self.conn.execute(sql, args):
            yield Received(*r)

    def greenhouses(self) -> list[tuple[str, str]]:
        return [tuple(r) for r in self.conn.execute(
            "SELECT DISTINCT farm, greenhouse FROM messages WHERE kind LIKE 'measurement/%' "
            "ORDER BY farm, greenhouse")]

    def close(self) -> None:
        self.conn.close()

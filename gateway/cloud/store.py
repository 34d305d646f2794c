"""The cloud side's store: every message received, once, by idempotency key.

:class:`CloudStore` is the interface the subscriber writes through and answers history queries
from; :class:`SqliteCloudStore` is the embedded default and ``gateway.cloud.postgres.PgStore``
(``subscribe --dsn``) the fleet's, with ``INSERT ... ON CONFLICT DO NOTHING`` on the same
idempotency key. :func:`open_store` picks one.

Table ``messages``: ``seq`` (arrival order of first receipt), ``idem`` (unique), ``key``,
``farm``, ``greenhouse``, ``kind``, ``t`` (observation time from the payload [unix s]),
``payload`` (the JSON as received), ``received`` (wall time [unix s]).
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Protocol

from gateway.publish import keyspace as K

TIME_ATTRS = ("dateObserved", "dateIssued", "dateModified")
MAX_LIMIT = 100_000  # history replies per query


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
    """What the subscriber needs from a store (SQLite here, PostgreSQL in postgres.py)."""

    def add(self, messages: Sequence[Received]) -> int:
        """Store the messages not seen before (by idempotency key) in one transaction; returns
        how many were new. Raises when nothing could be stored (the caller keeps the batch)."""
        ...

    def count(self, farm: str | None = None) -> int: ...

    def messages(self, farm: str | None = None, greenhouse: str | None = None,
                 kind: str | None = None) -> Iterator[Received]:
        """Stored messages in arrival order (first receipt)."""
        ...

    def greenhouses(self) -> list[tuple[str, str]]:
        """(farm, greenhouse) pairs that have measurements."""
        ...

    def history(self, farm: str, greenhouse: str | None = None, kind: str | None = None,
                t_from: float | None = None, t_to: float | None = None, limit: int = 1000,
                match: Callable[[str], bool] | None = None, last: int | None = None) -> list[Received]:
        """Messages of `farm` (a greenhouse and kind, or any when None; a kind ending in
        ``/**`` takes every kind below it) observed in [t_from, t_to], oldest first, at most
        `limit`; `match(key)`, when given, must also accept the message key. With `last`, only
        the newest `last` of each key (then the newest `limit` of those), as a gateway's
        ``?last=N`` answers."""
        ...

    def latest(self) -> dict[str, float]:
        """Farm → the newest observation time stored [unix s] (where a catch-up starts)."""
        ...

    def reader(self) -> CloudStore:
        """Another connection to the same store, for queries from another thread."""
        ...

    def close(self) -> None: ...


def open_store(db: str | Path | None = None, dsn: str | None = None, schema: str = "serra") -> CloudStore:
    """PostgreSQL when a DSN is given (needs the ``cloud`` extra, psycopg 3), else SQLite at `db`."""
    if dsn:
        from gateway.cloud.postgres import PgStore

        return PgStore.connect(dsn, schema=schema)
    if db is None:
        raise ValueError("a cloud store needs an SQLite file or a PostgreSQL DSN")
    return SqliteCloudStore(db)


def check_history_limits(limit: int, last: int | None) -> None:
    if not 1 <= limit <= MAX_LIMIT:
        raise ValueError(f"limit {limit}: expected 1..{MAX_LIMIT}")
    if last is not None and not 1 <= last <= MAX_LIMIT:
        raise ValueError(f"last {last}: expected 1..{MAX_LIMIT}")


def kind_clause(kind: str) -> tuple[str, list[str]]:
    """SQL for a kind filter: exact, or ``stem/**`` = stem and every kind below it."""
    if kind.endswith("/**"):
        stem = kind[:-3]
        escaped = stem.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
        return "(kind = %s OR kind LIKE %s ESCAPE '\\')", [stem, escaped + "/%"]
    return "kind = %s", [kind]


class StoreConfigError(RuntimeError):
    """The store's settings are wrong on their face (a DSN that does not parse, a bad schema
    name, a file that is another database): no retry can help, unlike a server that does not
    answer. ``subscribe`` exits 78 (EX_CONFIG) on it, which its unit does not restart."""


class NotACloudStore(StoreConfigError):
    """An SQLite file that is another database; the message names it."""


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
        self._refuse_other_database()
        self.conn.execute("PRAGMA journal_mode=WAL")
        self.conn.execute("PRAGMA synchronous=FULL")
        self.conn.executescript(self.DDL)

    def _refuse_other_database(self) -> None:
        """A file with tables of its own (the gateway's serra.db given for cloud.db, a mix-up
        the two SQLite stores invite) is refused before this store adds its table to it."""
        tables = {r[0] for r in self.conn.execute(
            "SELECT name FROM sqlite_master WHERE type='table'")}
        other = sorted(tables - {"messages", "sqlite_sequence"})
        if other:
            self.conn.close()
            gateway = " (the gateway's own store? 'python -m gateway export' reads that)" if {
                "samples", "minute"} <= tables else ""
            raise NotACloudStore(f"{self.path}: not a cloud store: it holds other tables "
                                 f"({', '.join(other[:4])}{', ...' if len(other) > 4 else ''})"
                                 f"{gateway}; give the cloud store a file of its own")

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

    def count(self, farm: str | None = None) -> int:
        if farm is None:
            return self.conn.execute("SELECT count(*) FROM messages").fetchone()[0]
        return self.conn.execute("SELECT count(*) FROM messages WHERE farm=?", (farm,)).fetchone()[0]

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

    def history(self, farm: str, greenhouse: str | None = None, kind: str | None = None,
                t_from: float | None = None, t_to: float | None = None, limit: int = 1000,
                match: Callable[[str], bool] | None = None, last: int | None = None) -> list[Received]:
        check_history_limits(limit, last)
        where = ["farm = ?", "t IS NOT NULL"]
        args: list[str | float] = [farm]
        if greenhouse is not None:
            where.append("greenhouse = ?")
            args.append(greenhouse)
        if kind is not None and kind != "**":
            clause, more = kind_clause(kind)
            where.append(clause.replace("%s", "?"))
            args += more
        for op, t in ((">=", t_from), ("<=", t_to)):
            if t is not None:
                where.append(f"t {op} ?")
                args.append(t)
        cols = "key, payload, idem, farm, greenhouse, kind, t, received"
        query = f"SELECT {cols} FROM messages WHERE {' AND '.join(where)} ORDER BY t, seq"
        if last is not None:  # the newest `last` of each key, still oldest first
            query = (f"SELECT {cols} FROM (SELECT *, row_number() OVER (PARTITION BY key "
                     f"ORDER BY t DESC, seq DESC) AS nth FROM messages WHERE {' AND '.join(where)}) "
                     "WHERE nth <= ? ORDER BY t, seq")
            args.append(last)
        out: list[Received] = []
        for r in self.conn.execute(query, args):
            if match is None or match(r[0]):
                out.append(Received(*r))
                if last is None and len(out) >= limit:
                    break
        return out[-limit:]

    def latest(self) -> dict[str, float]:
        return {f: t for f, t in self.conn.execute(
            "SELECT farm, max(t) FROM messages WHERE t IS NOT NULL GROUP BY farm")}

    def reader(self) -> SqliteCloudStore:
        return SqliteCloudStore(self.path)

    def close(self) -> None:
        self.conn.close()

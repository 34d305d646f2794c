"""The cloud history store on PostgreSQL (psycopg 3): many farms' messages in one table.

    store = PgStore.connect("postgresql://serra@db.example.org/serra")   # creates the schema
    store.insert_batch(messages)      # -> rows inserted; repeats are dropped, never doubled
    store.history("farm-a", "gh1", "measurement/inside", t_from, t_to, limit=1000)
    store.close()

It implements ``gateway.cloud.store.CloudStore`` (``add`` is ``insert_batch``), so
``python -m gateway subscribe --dsn DSN`` stores here and answers history queries from here.

The table ``serra.message`` (schema name configurable) is what a cloud engineer queries::

    SELECT observed, payload->>'temperature' FROM serra.message
     WHERE farm = 'farm-a' AND greenhouse = 'gh1' AND kind = 'measurement/inside'
       AND observed >= '2026-11-01' ORDER BY observed;

An idempotency key is unique per farm (``UNIQUE (farm, idem)``): a message delivered twice
(an outbox resending after a reconnection, two routers, a replay) is stored once, and one farm
cannot shadow another farm's keys. Payloads are JSONB (their text comes back normalised).
"""

from __future__ import annotations

import logging
import re
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

try:
    import psycopg
    from psycopg import sql
except ImportError as exc:  # an optional dependency: the gateway appliance never needs it
    # the wheel's cloud extra, named by its content: 'serra[cloud]' by name would come from an index
    raise ImportError("the PostgreSQL cloud store needs psycopg 3 (the cloud extra): "
                      "pip install 'psycopg[binary]>=3.1'") from exc

from gateway.cloud.store import (  # noqa: E402
    Received,
    StoreConfigError,
    check_history_limits,
    kind_clause,
)

log = logging.getLogger("serra.cloud.postgres")
SCHEMA_VERSION = 1
CHUNK = 10_000  # rows per INSERT statement (arrays of this length)
_SCHEMA_NAME = re.compile(r"^[a-z_][a-z0-9_]{0,62}$")

DDL = """
CREATE SCHEMA IF NOT EXISTS {schema};
CREATE TABLE IF NOT EXISTS {schema}.message (
    id         bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    farm       text        NOT NULL,
    greenhouse text        NOT NULL,
    kind       text        NOT NULL,   -- measurement/inside, forecast, device/7, ...
    observed   timestamptz NOT NULL,   -- what the message is about (gateway clock)
    received   timestamptz NOT NULL,   -- when the subscriber got it
    stored     timestamptz NOT NULL DEFAULT now(),
    key        text        NOT NULL,   -- the Zenoh key expression it came on
    idem       text        NOT NULL,   -- the idempotency key
    payload    jsonb       NOT NULL,
    CONSTRAINT message_farm_idem UNIQUE (farm, idem)
);
CREATE INDEX IF NOT EXISTS message_series ON {schema}.message (farm, greenhouse, kind, observed);
CREATE INDEX IF NOT EXISTS message_farm_time ON {schema}.message (farm, observed);
CREATE TABLE IF NOT EXISTS {schema}.schema_version (version integer NOT NULL);
"""

INSERT = """
INSERT INTO {schema}.message (farm, greenhouse, kind, observed, received, key, idem, payload)
SELECT f, g, k, to_timestamp(o), to_timestamp(r), ke, i, p::jsonb
  FROM unnest(%s::text[], %s::text[], %s::text[], %s::float8[], %s::float8[], %s::text[],
              %s::text[], %s::text[]) AS m(f, g, k, o, r, ke, i, p)
ON CONFLICT (farm, idem) DO NOTHING
"""


class CloudStoreError(RuntimeError):
    """The store cannot do its job (connection, schema); one line, no password in it."""


class PgConfigError(CloudStoreError, StoreConfigError):
    """A DSN that does not parse or a bad schema name: found without the server."""


class MessageLike(Protocol):
    """What insert_batch reads from a message (the subscriber's record, or CloudMessage).
    Read-only members, so a frozen dataclass (``Received``) is one."""

    @property
    def key(self) -> str: ...
    @property
    def idem(self) -> str: ...
    @property
    def farm(self) -> str: ...
    @property
    def greenhouse(self) -> str: ...
    @property
    def kind(self) -> str: ...
    @property
    def t(self) -> float | None:
        """Observed [unix s]; None: the message had no time (stored as received)."""
        ...
    @property
    def payload(self) -> str:
        """JSON text."""
        ...
    @property
    def received(self) -> float:
        """[unix s]"""
        ...


CloudMessage = Received  # one record type for every cloud store (gateway.cloud.store)


@dataclass(frozen=True)
class Rejected:
    idem: str
    key: str
    reason: str


def redact(dsn: str) -> str:
    """The DSN without its password, for messages."""
    try:
        parts = psycopg.conninfo.conninfo_to_dict(dsn)
    except psycopg.Error:
        return "<unparsable DSN>"
    parts.pop("password", None)
    return " ".join(f"{k}={v}" for k, v in parts.items()) or "<default connection>"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


class PgStore:
    """Messages of many farms in PostgreSQL; one connection, used by one thread at a time."""

    def __init__(self, conn: psycopg.Connection, dsn: str, schema: str = "serra") -> None:
        self.conn, self.dsn, self.schema = conn, dsn, schema
        self.rejected: list[Rejected] = []  # messages refused for bad payloads (logged too)
        self.reconnecting = False  # the connection was lost and re-opening it has failed so far
        self._insert = sql.SQL(INSERT).format(schema=sql.Identifier(schema))

    @classmethod
    def connect(cls, dsn: str, schema: str = "serra", create: bool = True,
                connect_timeout: float = 10.0) -> PgStore:
        if not _SCHEMA_NAME.match(schema):
            raise PgConfigError(f"schema name {schema!r}: use lower-case letters, digits and _")
        try:  # the syntax alone, before any server is asked (a refusal by one may be transient)
            psycopg.conninfo.conninfo_to_dict(dsn)
        except psycopg.Error as exc:
            raise PgConfigError(f"PostgreSQL DSN: {_first_line(exc)} (the DSN is not shown: it "
                               "may hold a password)") from None
        store = cls(cls._open(dsn, connect_timeout), dsn, schema)
        if create:
            store.create_schema()
        return store

    @staticmethod
    def _open(dsn: str, connect_timeout: float) -> psycopg.Connection:
        try:
            return psycopg.connect(dsn, connect_timeout=max(1, round(connect_timeout)))
        except psycopg.Error as exc:
            raise CloudStoreError(f"PostgreSQL ({redact(dsn)}): cannot connect: "
                                  f"{_first_line(exc)}") from None

    def create_schema(self) -> None:
        """Tables and indexes, if missing (several subscribers may start at once: locked)."""
        ddl = sql.SQL(DDL).format(schema=sql.Identifier(self.schema))
        try:
            with self.conn.transaction():
                self.conn.execute("SELECT pg_advisory_xact_lock(hashtext('serra.schema'))")
                self.conn.execute(ddl)
                row = self.conn.execute(sql.SQL("SELECT max(version) FROM {}.schema_version")
                                        .format(sql.Identifier(self.schema))).fetchone()
                if row is None or row[0] is None:
                    self.conn.execute(sql.SQL("INSERT INTO {}.schema_version VALUES (%s)")
                                      .format(sql.Identifier(self.schema)), (SCHEMA_VERSION,))
                elif row[0] > SCHEMA_VERSION:
                    raise CloudStoreError(f"schema {self.schema} is version {row[0]}, newer than "
                                          f"this code ({SCHEMA_VERSION}): upgrade Serra")
        except psycopg.Error as exc:
            raise CloudStoreError(f"PostgreSQL ({redact(self.dsn)}): cannot create schema "
                                  f"{self.schema}: {_first_line(exc)}") from None

    def insert_batch(self, messages: Iterable[MessageLike]) -> int:
        """Store `messages` in one transaction; returns how many were new. A repeat (same farm
        and idempotency key) is dropped. A message PostgreSQL refuses (a payload that is not
        JSON, a NaN time, a NUL character) is left out, logged and kept in `rejected`; the rest
        of the batch is stored. A lost connection is re-opened once; if that fails,
        CloudStoreError, and nothing of the batch was stored (the caller keeps it)."""
        batch = list(messages)
        if not batch:
            return 0
        try:
            return self._insert_all(batch)
        except psycopg.OperationalError as exc:
            if not self.conn.closed and not self.conn.broken:
                raise CloudStoreError(f"PostgreSQL ({redact(self.dsn)}): {_first_line(exc)}") from None
            if not self.reconnecting:  # once per outage, not once per retried batch
                log.warning("PostgreSQL connection lost (%s); reconnecting", _first_line(exc))
            self.reconnecting = True
            self.conn = self._open(self.dsn, 10.0)
            self.reconnecting = False
            try:
                return self._insert_all(batch)
            except psycopg.Error as again:
                raise CloudStoreError(f"PostgreSQL ({redact(self.dsn)}): {_first_line(again)}") from None

    def _insert_all(self, batch: list[MessageLike]) -> int:
        try:
            with self.conn.transaction():
                return sum(self._insert_chunk(batch[i:i + CHUNK]) for i in range(0, len(batch), CHUNK))
        except psycopg.DataError:
            pass  # some row is not storable: find it, store the others
        inserted = 0
        with self.conn.transaction():
            for m in batch:
                try:
                    with self.conn.transaction():  # a savepoint per row, on this rare path only
                        inserted += self._insert_chunk([m])
                except psycopg.DataError as exc:
                    reason = _first_line(exc)
                    log.warning("message %s on %s not stored: %s", m.idem, m.key, reason)
                    self.rejected.append(Rejected(m.idem, m.key, reason))
        return inserted

    def _insert_chunk(self, chunk: Sequence[MessageLike]) -> int:
        columns: list[list[Any]] = [[] for _ in range(8)]
        for m in chunk:
            observed = m.t if m.t is not None else m.received
            row = (str(m.farm), str(m.greenhouse), str(m.kind), float(observed), float(m.received),
                   str(m.key), str(m.idem), str(m.payload))
            for col, value in zip(columns, row, strict=True):
                col.append(value)
        cur = self.conn.execute(self._insert, columns)
        return max(cur.rowcount, 0)

    add = insert_batch  # the CloudStore interface

    def history(self, farm: str, greenhouse: str | None = None, kind: str | None = None,
                t_from: float | None = None, t_to: float | None = None,
                limit: int = 1000, match: Callable[[str], bool] | None = None,
                last: int | None = None) -> list[Received]:
        """Messages of `farm` (a greenhouse and kind, or every one when None; a kind ending in
        ``/**`` takes every kind below it) observed in [t_from, t_to], oldest first, at most
        `limit` (1..100000). `match(key)`, when given, must also accept the message's key (a
        history query's wildcards; rows are then read through a server-side cursor). With
        `last`, only the newest `last` of each key (then the newest `limit` of those)."""
        check_history_limits(limit, last)
        where = [sql.SQL("farm = %s")]
        args: list[Any] = [farm]
        if greenhouse not in (None, "*", "**"):
            where.append(sql.SQL("greenhouse = %s"))
            args.append(greenhouse)
        if kind is not None and kind != "**":
            clause, more = kind_clause(kind)
            where.append(sql.SQL(clause))
            args += more
        if t_from is not None:
            where.append(sql.SQL("observed >= to_timestamp(%s)"))
            args.append(t_from)
        if t_to is not None:
            where.append(sql.SQL("observed <= to_timestamp(%s)"))
            args.append(t_to)
        rows_of = sql.SQL("{}.message WHERE {}").format(sql.Identifier(self.schema),
                                                       sql.SQL(" AND ").join(where))
        if last is not None:  # the newest `last` of each key, still oldest first
            rows_of = sql.SQL("(SELECT *, row_number() OVER (PARTITION BY key ORDER BY observed "
                              "DESC, id DESC) AS nth FROM {}) newest WHERE nth <= %s").format(rows_of)
            args.append(last)
        query = sql.SQL(
            "SELECT key, payload::text, idem, farm, greenhouse, kind, "
            "extract(epoch FROM observed)::float8, extract(epoch FROM received)::float8 "
            "FROM {} ORDER BY observed, id").format(rows_of)
        if last is not None:
            return list(self._scan(query, args, None, match))[-limit:]
        if match is None:
            rows = self.conn.execute(query + sql.SQL(" LIMIT %s"), [*args, limit]).fetchall()
            self.conn.commit()  # end the read transaction: no idle-in-transaction connection
            return [Received(*row) for row in rows]
        return list(self._scan(query, args, limit, match))

    def _scan(self, query: sql.Composed, args: list[Any], limit: int | None = None,
              match: Callable[[str], bool] | None = None) -> Iterator[Received]:
        """Rows through a server-side cursor (never all in memory), filtered by `match`."""
        n = 0
        with self.conn.transaction(), self.conn.cursor(name=f"serra_{uuid.uuid4().hex}") as cur:
            cur.itersize = 1000
            cur.execute(query, args)
            for row in cur:
                if match is None or match(row[0]):
                    yield Received(*row)
                    n += 1
                    if limit is not None and n >= limit:
                        return

    def messages(self, farm: str | None = None, greenhouse: str | None = None,
                 kind: str | None = None) -> Iterator[Received]:
        """Stored messages in arrival order (first receipt)."""
        where, args = [], []
        for col, value in (("farm", farm), ("greenhouse", greenhouse), ("kind", kind)):
            if value is not None:
                where.append(sql.SQL("{} = %s").format(sql.Identifier(col)))
                args.append(value)
        query = sql.SQL(
            "SELECT key, payload::text, idem, farm, greenhouse, kind, "
            "extract(epoch FROM observed)::float8, extract(epoch FROM received)::float8 "
            "FROM {}.message{} ORDER BY id").format(
                sql.Identifier(self.schema),
                sql.SQL(" WHERE ") + sql.SQL(" AND ").join(where) if where else sql.SQL(""))
        return iter(list(self._scan(query, args)))

    def greenhouses(self) -> list[tuple[str, str]]:
        rows = self.conn.execute(sql.SQL(
            "SELECT DISTINCT farm, greenhouse FROM {}.message WHERE kind LIKE 'measurement/%%' "
            "ORDER BY farm, greenhouse").format(sql.Identifier(self.schema))).fetchall()
        self.conn.commit()
        return [(str(f), str(g)) for f, g in rows]

    def latest(self) -> dict[str, float]:
        rows = self.conn.execute(sql.SQL(
            "SELECT farm, extract(epoch FROM max(observed))::float8 FROM {}.message "
            "WHERE observed IS NOT NULL GROUP BY farm").format(sql.Identifier(self.schema))).fetchall()
        self.conn.commit()
        return {str(f): float(t) for f, t in rows}

    def reader(self) -> PgStore:
        """A second connection (one connection serves one thread at a time)."""
        return PgStore.connect(self.dsn, self.schema, create=False)

    @property
    def path(self) -> str:
        """Where the store is, for messages (the DSN without its password)."""
        return redact(self.dsn)

    def count(self, farm: str | None = None) -> int:
        query = sql.SQL("SELECT count(*) FROM {}.message").format(sql.Identifier(self.schema))
        if farm is not None:
            query = query + sql.SQL(" WHERE farm = %s")
        row = self.conn.execute(query, [farm] if farm is not None else []).fetchone()
        self.conn.commit()
        return int(row[0]) if row else 0

    def close(self) -> None:
        self.conn.close()


"""The outbox: every message to publish, durable, in order, never dropped (docs/store.md).

Producers add messages inside their own transaction, together with the cursor of what they
have turned into messages, so a crash never loses a message nor makes one twice. The publisher
(gateway/publish/publisher.py) puts them in ``id`` order and marks them sent. Sent rows stay as
the log the history queryable answers from, until retention removes them.

Bounded: at most ``max_rows`` unsent messages. A producer that finds no room raises
:class:`OutboxFull` and keeps its cursor: nothing is dropped, production pauses (the data stays
in the store's own tables) and resumes as the backlog drains. An alarm is raised from
``alarm_fraction`` of the bound, before it fills.
"""

from __future__ import annotations

import logging
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import dataclass

from gateway.store.db import transaction

log = logging.getLogger("serra.store.outbox")


@dataclass(frozen=True)
class Message:
    """One message to publish. ``idem`` is its idempotency key: stable, derived from what the
    message is about (never from when it was made), so the cloud side can drop repeats."""

    key: str
    kind: str
    t: float  # observation time [unix s, gateway clock]
    idem: str
    payload: str


@dataclass(frozen=True)
class Pending:
    """An unsent message as the publisher reads it."""

    id: int
    key: str
    idem: str
    payload: str


class OutboxFull(Exception):
    """No room for the messages a producer wants to add: it must keep its cursor and retry."""


class Outbox:
    """FIFO of messages in SQLite, bounded to ``max_rows`` unsent rows, alarm at
    ``alarm_fraction`` of that."""

    def __init__(self, conn: sqlite3.Connection, max_rows: int = 100_000,
                 alarm_fraction: float = 0.8) -> None:
        if max_rows < 1 or not 0 < alarm_fraction <= 1:
            raise ValueError(f"outbox: max_rows {max_rows} must be >= 1 and alarm_fraction "
                             f"{alarm_fraction} in (0, 1]")
        self.conn = conn
        self.max_rows = max_rows
        self.alarm_at = max(1, int(max_rows * alarm_fraction))
        self.alarm = False
        self.refused = 0  # messages a producer could not add (it retries later)

    def pending(self) -> int:
        return self.conn.execute("SELECT count(*) FROM outbox WHERE sent IS NULL").fetchone()[0]

    def room(self) -> int:
        return max(0, self.max_rows - self.pending())

    def add(self, messages: Sequence[Message], now: float | None = None) -> int:
        """Insert ``messages`` in the caller's open transaction; returns how many were new (a
        message whose idempotency key is already there is not added twice).

        Raises :class:`OutboxFull` (nothing added) when they do not all fit."""
        if not messages:
            return 0
        n = self.pending()
        if n + len(messages) > self.max_rows:
            self.refused += len(messages)
            self._set_alarm(n)
            raise OutboxFull(f"outbox holds {n} unsent messages of {self.max_rows}: "
                             f"{len(messages)} more wait in the store")
        now = time.time() if now is None else now
        before = self.conn.total_changes
        self.conn.executemany(
            "INSERT OR IGNORE INTO outbox (created, key, payload, kind, t, idem) "
            "VALUES (?, ?, ?, ?, ?, ?)",
            [(now, m.key, m.payload, m.kind, m.t, m.idem) for m in messages])
        added = self.conn.total_changes - before
        self._set_alarm(n + added)
        return added

    def put(self, message: Message, now: float | None = None) -> int:
        """Add one message in its own transaction (raises :class:`OutboxFull` when full)."""
        with transaction(self.conn):
            return self.add([message], now)

    def _set_alarm(self, n: int) -> None:
        alarm = n >= self.alarm_at
        if alarm and not self.alarm:
            log.warning("outbox alarm: %d/%d unsent messages (nobody subscribed, or the link is "
                        "down); production pauses when full, nothing is dropped", n, self.max_rows)
        elif self.alarm and not alarm:
            log.info("outbox alarm cleared: %d/%d unsent messages", n, self.max_rows)
        self.alarm = alarm

    def peek(self, limit: int = 100, after: int = 0) -> list[Pending]:
        """The oldest unsent messages with ``id > after``, in order."""
        return [Pending(*r) for r in self.conn.execute(
            "SELECT id, key, idem, payload FROM outbox WHERE sent IS NULL AND id > ? "
            "ORDER BY id LIMIT ?", (after, limit))]

    def mark_sent(self, ids: Sequence[int], now: float | None = None) -> None:
        now = time.time() if now is None else now
        with transaction(self.conn):
            self.conn.executemany("UPDATE outbox SET sent=?, attempts=attempts+1 WHERE id=?",
                                  [(now, i) for i in ids])

    def sent_recently(self, seconds: float) -> list[Pending]:
        """The messages sent in the last ``seconds`` before the newest send, in order.

        The publisher puts them again at start: a message handed to Zenoh just before a crash may
        still have been in its queues. Their ``sent`` time is left as it was, so a restart that
        sends nothing new finds the same ones again (and nothing snowballs). Repeats cost the
        cloud nothing: it drops them by idempotency key."""
        return [Pending(*r) for r in self.conn.execute(
            "SELECT id, key, idem, payload FROM outbox WHERE sent >= "
            "(SELECT max(sent) FROM outbox) - ? ORDER BY id", (seconds,))]

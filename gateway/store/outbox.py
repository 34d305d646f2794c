"""Bounded outbox of messages waiting to be published (consumed by the publisher)."""

from __future__ import annotations

import logging
import sqlite3
import time

from gateway.store.db import transaction

log = logging.getLogger("serra.store.outbox")


class Outbox:
    """FIFO in SQLite. Alarm at `alarm_fraction` of `max_rows`; when full the oldest unsent
    message is dropped (and counted) so that fresh data keeps flowing."""

    def __init__(self, conn: sqlite3.Connection, max_rows: int = 100_000,
                 alarm_fraction: float = 0.8) -> None:
        self.conn = conn
        self.max_rows = max_rows
        self.alarm_at = int(max_rows * alarm_fraction)
        self.dropped = 0
        self.alarm = False

    def pending(self) -> int:
        return self.conn.execute("SELECT count(*) FROM outbox WHERE sent IS NULL").fetchone()[0]

    def put(self, key: str, payload: str, now: float | None = None) -> None:
        now = time.time() if now is None else now
        with transaction(self.conn):
            n = self.pending()
            if n >= self.max_rows:
                drop = n - self.max_rows + 1
                self.conn.execute("DELETE FROM outbox WHERE id IN (SELECT id FROM outbox "
                                  "WHERE sent IS NULL ORDER BY id LIMIT ?)", (drop,))
                self.dropped += drop
            self.conn.execute("INSERT INTO outbox (created, key, payload) VALUES (?, ?, ?)",
                              (now, key, payload))
        alarm = n + 1 >= self.alarm_at
        if alarm and not self.alarm:
            log.warning("outbox %d/%d messages: publisher not keeping up", n + 1, self.max_rows)
        self.alarm = alarm

    def peek(self, limit: int = 100) -> list[tuple[int, str, str]]:
        return list(self.conn.execute(
            "SELECT id, key, payload FROM outbox WHERE sent IS NULL ORDER BY id LIMIT ?",
            (limit,)))

    def mark_sent(self, ids: list[int], now: float | None = None) -> None:
        now = time.time() if now is None else now
        with transaction(self.conn):
            self.conn.executemany("UPDATE outbox SET sent=? WHERE id=?", [(now, i) for i in ids])

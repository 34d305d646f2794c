"""The history queryable: ``serra/<farm>/<greenhouse>/history/<kind>?from=ISO;to=ISO;limit=N``
(or ``?last=N``: the newest N messages of each key matched, e.g. the latest of everything).

Answered from the gateway's own store (the outbox is also the log of every message made, sent or
not, kept ``history_days``): each reply is the stored payload, unchanged (same idempotency key,
so a cloud can merge history with what it received live), on the key
``serra/<farm>/<greenhouse>/history/<kind>``, oldest first by observation time, at most ``limit``
replies in all (default 1000). Wildcards work (``serra/farm1/*/history/measurement/**``). A bad
parameter gets one error reply naming it. Ask with ``ConsolidationMode.NONE``: Zenoh keeps only the
latest reply per key otherwise.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from pathlib import Path

import zenoh

from gateway.publish import keyspace as K

log = logging.getLogger("serra.publish")
KEYS_TTL = 600.0  # [s] between full listings of the stored keys (drops keys retention emptied)


class HistoryQueryable:
    """Declared on ``serra/<farm>/*/history/**`` with its own read-only SQLite connection."""

    def __init__(self, session: zenoh.Session, db: Path, farm: str) -> None:
        self.conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, check_same_thread=False,
                                    timeout=30)
        self.conn.execute("PRAGMA busy_timeout=30000")
        self.lock = threading.Lock()
        self._keys: set[str] = set()
        self._keys_at = -KEYS_TTL
        self._keys_id = 0  # the outbox id up to which _keys is complete
        self.answered = 0
        self.queryable = session.declare_queryable(
            f"{K.PREFIX}/{farm}/*/{K.HISTORY}/**", self._on_query, complete=False)

    def close(self) -> None:
        """Undeclare (before the session closes: a declared callback blocks interpreter exit)."""
        try:
            self.queryable.undeclare()
        except zenoh.ZError:
            pass
        with self.lock:
            self.conn.close()

    def _stored_keys(self) -> list[str]:
        """Every key in the outbox. A full listing scans the table, so between two (every
        :data:`KEYS_TTL`) only the rows added since the last look are read: a key made a moment
        ago is answered at once (a cloud subscriber's catch-up asks as soon as it joins)."""
        top = self.conn.execute("SELECT coalesce(max(id), 0) FROM outbox").fetchone()[0]
        if time.monotonic() - self._keys_at > KEYS_TTL:
            self._keys = {k for k, in self.conn.execute(
                "SELECT DISTINCT key FROM outbox WHERE id <= ?", (top,))}
            self._keys_at = time.monotonic()
        elif top > self._keys_id:  # the rowid range since the last look: cheap
            self._keys.update(k for k, in self.conn.execute(
                "SELECT DISTINCT key FROM outbox WHERE id > ? AND id <= ?", (self._keys_id, top)))
        self._keys_id = top
        return sorted(self._keys)

    def _on_query(self, query: zenoh.Query) -> None:
        with query:
            if (rng := K.query_range(query)) is None:
                return
            asked = query.key_expr
            try:
                with self.lock:
                    keys = [k for k in self._stored_keys()
                            if k.startswith(K.PREFIX + "/") and asked.intersects(K.history_key(k))]
                    rows = self._rows(keys, rng) if keys else []
            except sqlite3.Error as e:
                log.warning("history query %s failed: %s", asked, e)
                query.reply_err(f"store error: {e}")
                return
            for key, payload in rows:
                query.reply(K.history_key(key), payload, encoding=zenoh.Encoding.APPLICATION_JSON)
            self.answered += 1

    def _rows(self, keys: list[str], rng: K.HistoryRange) -> list[tuple[str, str]]:
        marks = ", ".join("?" * len(keys))
        start = rng.start if rng.start > -1e300 else -1e300
        end = rng.end if rng.end < 1e300 else 1e300
        if rng.last is not None:  # one index range per key (outbox_key_t), newest first
            rows = []
            for k in keys:
                rows += self.conn.execute(
                    "SELECT t, id, key, payload FROM outbox WHERE key=? AND t >= ? AND t <= ? "
                    "ORDER BY t DESC, id DESC LIMIT ?", (k, start, end, rng.last)).fetchall()
            return [(r[2], r[3]) for r in sorted(rows)[-rng.limit:]]
        return self.conn.execute(
            f"SELECT key, payload FROM outbox WHERE key IN ({marks}) AND t >= ? AND t <= ? "
            "ORDER BY t, id LIMIT ?", (*keys, start, end, rng.limit)).fetchall()

"""History queries answered by the cloud store (``subscribe --history``): the same selector as a
gateway's (``serra/<farm>/<greenhouse>/history/<kind>?from=ISO;to=ISO;limit=N``, or ``last=N``:
the newest N of each key; docs/cloud.md), the same replies (stored payloads, oldest first, on
``serra/<farm>/<greenhouse>/history/<kind>``), from every farm the store holds rather than one
gateway's last ``history_days``.

One queryable per farm, ``serra/<farm>/*/history/**``: behind the routers' access control a
store may declare a queryable only on the farms its certificate has ``store = true`` rights for
(gateway/net/acl.py). They are declared *complete*: a query with Zenoh's default target
(``BEST_MATCHING``) is answered by the cloud store alone, without crossing to the farms; ask with
``target=QueryTarget.ALL`` to also reach the gateways (duplicates share idempotency keys).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from gateway.cloud.keyexpr import history_filter
from gateway.cloud.store import CloudStore
from gateway.publish import keyspace as K

log = logging.getLogger("serra.cloud")


class CloudHistory:
    """Queryables over a store's own reader connection (queries come on Zenoh's threads)."""

    def __init__(self, session: zenoh.Session, store: CloudStore, farms: Sequence[str],
                 complete: bool = True) -> None:
        self.store = store.reader()
        self.lock = threading.Lock()  # one connection: one query at a time
        self.answered = 0
        self.errors = 0
        self.queryables: list[Any] = []
        try:
            for farm in farms:
                self.queryables.append(session.declare_queryable(
                    f"{K.PREFIX}/{farm}/*/{K.HISTORY}/**",
                    self._handler(farm), complete=complete))
        except BaseException:
            self.close()
            raise

    def _handler(self, farm: str) -> Callable[[zenoh.Query], None]:
        return lambda q: self._on_query(q, farm)

    def _on_query(self, query: zenoh.Query, farm: str) -> None:
        with query:
            if (rng := K.query_range(query)) is None:
                return
            f = history_filter(str(query.key_expr))
            if f.farm not in (None, farm):
                return  # another farm's queryable of ours answers it
            start = rng.start if rng.start > -1e300 else None
            end = rng.end if rng.end < 1e300 else None
            try:
                with self.lock:
                    rows = self.store.history(farm, f.greenhouse, f.kind, start, end, rng.limit,
                                              match=f.wants, last=rng.last)
            except Exception as e:  # the store failed: the asker gets one error reply
                self.errors += 1
                log.warning("history query %s failed: %s", query.key_expr, e)
                query.reply_err(f"store error: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
                return
            for m in rows:
                query.reply(K.history_key(m.key), m.payload, encoding=zenoh.Encoding.APPLICATION_JSON)
            self.answered += 1

    def close(self) -> None:
        """Undeclare (before the session closes), then close the reader connection."""
        for q in self.queryables:
            try:
                q.undeclare()
            except zenoh.ZError:
                pass
        self.queryables = []
        with self.lock:
            self.store.close()

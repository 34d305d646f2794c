"""Durable storage on SQLite (WAL): samples, device state, minute aggregates, estimates, outbox.

The one writer opens the store with `Store` (or `open_db`); readers (export, the status screen,
any tool that only reads) with `open_readonly`, which changes nothing and refuses a file that
is not a Serra store with a `StoreError` naming it.
"""

from gateway.store.db import Store, StoreError, open_db, open_readonly

__all__ = ["Store", "StoreError", "open_db", "open_readonly"]

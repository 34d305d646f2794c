"""Durable storage on SQLite (WAL): samples, device state, minute aggregates, estimates, outbox."""

from gateway.store.db import Store, open_db

__all__ = ["Store", "open_db"]

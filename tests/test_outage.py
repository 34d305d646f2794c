"""gateway/store/outage.py on real SQLite errors: which are waited out (and how they are said),
which stop the service, which are none of the store's; one line per outage, a reminder, the
backoff, the "back" line once every part that failed has written again."""

from __future__ import annotations

import logging
import sqlite3
from pathlib import Path

import pytest

from gateway.store import Store
from gateway.store.db import StoreGone
from gateway.store.outage import REMIND_S, RETRY_MAX_S, Outage, StoreDamaged, cause, damaged


def full_error(tmp_path: Path) -> sqlite3.OperationalError:
    """SQLITE_FULL for real: a database capped at a few pages (PRAGMA max_page_count)."""
    c = sqlite3.connect(tmp_path / "capped.db")
    c.execute("CREATE TABLE t (x)")
    c.execute("PRAGMA max_page_count = 3")
    try:
        with pytest.raises(sqlite3.OperationalError) as e:
            for _ in range(100):
                c.execute("INSERT INTO t VALUES (?)", (b"x" * 4000,))
        return e.value
    finally:
        c.close()


def busy_error(tmp_path: Path) -> sqlite3.OperationalError:
    """SQLITE_BUSY for real: another connection holds the write lock."""
    path = tmp_path / "locked.db"
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("CREATE TABLE t (x)")
    holder.execute("BEGIN IMMEDIATE")
    other = sqlite3.connect(path, isolation_level=None, timeout=0)
    try:
        with pytest.raises(sqlite3.OperationalError) as e:
            other.execute("BEGIN IMMEDIATE")
        return e.value
    finally:
        other.close()
        holder.execute("ROLLBACK")
        holder.close()


def corrupt_error(tmp_path: Path) -> sqlite3.DatabaseError:
    """SQLITE_CORRUPT for real: a table's root page overwritten."""
    path = tmp_path / "corrupt.db"
    with sqlite3.connect(path) as c:
        c.execute("CREATE TABLE t (x)")
        c.executemany("INSERT INTO t VALUES (?)", [(b"y" * 1000,)] * 50)
    c.close()
    with open(path, "r+b") as f:
        f.seek(4096)  # page 2, the table's root: its header is no b-tree page's
        f.write(b"\xff" * 12)
    c = sqlite3.connect(path)
    try:
        with pytest.raises(sqlite3.DatabaseError) as e:
            c.execute("SELECT count(*), sum(length(x)) FROM t").fetchall()
        return e.value
    finally:
        c.close()


def test_causes_of_real_sqlite_errors(tmp_path: Path) -> None:
    db = tmp_path / "s.db"
    full = full_error(tmp_path)
    assert full.sqlite_errorname == "SQLITE_FULL"
    # a full disk says so; SQLITE_FULL with room on the disk is a size limit of another kind
    assert cause(full, db).startswith("no room (SQLite: database or disk is full; ")
    assert cause(full, db).endswith(" bytes free on its disk: a quota or a size limit?)")
    busy = busy_error(tmp_path)
    assert cause(busy, db) == "locked by another program (SQLite: database is locked)"
    assert cause(FileNotFoundError(2, "No such file or directory"), db) == \
        "no such file or directory"
    # none of the store's: the caller handles them as before
    with sqlite3.connect(":memory:") as c:
        c.execute("CREATE TABLE t (x UNIQUE)")
        c.execute("INSERT INTO t VALUES (1)")
        with pytest.raises(sqlite3.IntegrityError) as e:
            c.execute("INSERT INTO t VALUES (1)")
    c.close()
    assert cause(e.value, db) is None and damaged(e.value, db) is None
    assert cause(ValueError("a bug"), db) is None
    # a damaged file, a deleted one: the service stops
    bad = corrupt_error(tmp_path)
    assert bad.sqlite_errorname.startswith("SQLITE_CORRUPT") and cause(bad, db) is None
    stop = damaged(bad, db)
    assert stop is not None and str(stop).startswith(
        f"{db}: the store is damaged (SQLite: database disk image is malformed): stopping")
    store = Store(db)
    try:
        db.unlink()
        with pytest.raises(StoreGone) as gone:
            store.check_file()
    finally:
        store.close()
    assert str(damaged(gone.value, db)).startswith(
        f"{db}: the store file was deleted or replaced while open: stopping")


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_one_line_a_reminder_backoff_and_back_once_every_part_wrote(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    db = tmp_path / "s.db"
    full = full_error(tmp_path)
    clock, changes = Clock(), []
    o = Outage(db, "records not acked", lambda: changes.append(o.status_line()), clock)
    caplog.set_level(logging.INFO, "serra.store")
    delays = [o.failed("ingest", full) for _ in range(7)]
    assert delays == [1.0, 2.0, 4.0, 8.0, RETRY_MAX_S, RETRY_MAX_S, RETRY_MAX_S]
    assert o.failed("worker", full) == 1.0  # each part backs off on its own
    [line] = [r.getMessage() for r in caplog.records]
    assert line.startswith(f"{db}: no room (SQLite: database or disk is full; ")
    assert line.endswith("— records not acked; retrying with backoff (1 s doubling to every "
                         "10 s)")
    assert changes[0].startswith("STORE FAILING since ") and o.failing
    clock.t = REMIND_S
    o.failed("ingest", full)
    clock.t = REMIND_S + 1
    o.failed("ingest", full)
    assert len(caplog.records) == 2  # one reminder in ten minutes
    assert caplog.records[1].getMessage().startswith(
        f"{db}: still cannot be written, for 10 min now (9 failed writes): no room")
    o.ok("maintenance")  # never failed: nothing
    o.ok("ingest")  # the worker has not written yet
    assert o.failing and len(caplog.records) == 2
    clock.t = REMIND_S + 5
    o.ok("worker")
    assert not o.failing and changes[-1] == ""
    assert caplog.records[2].getMessage() == \
        f"{db}: back, writes succeed again after {REMIND_S + 5:.0f} s (10 failed writes)"
    status = o.status()
    assert status["failing"] is False and status["last"]["failures"] == 10
    assert status["last"]["cause"].startswith("no room")
    # a new outage starts its own line and its backoff anew
    assert o.failed("ingest", full) == 1.0 and len(caplog.records) == 4
    # what is no store fault is the caller's; a damaged store raises, said once
    assert o.failed("ingest", ValueError("a bug")) is None
    bad = corrupt_error(tmp_path)
    for _ in range(2):
        with pytest.raises(StoreDamaged):
            o.failed("worker", bad)
    assert len(caplog.records) == 5 and "the store is damaged" in caplog.records[4].getMessage()

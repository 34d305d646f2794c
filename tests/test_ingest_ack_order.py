"""The ingest core's promise, held still: a packet is acknowledged only after the transaction
holding it has committed (gateway/ingest/core.py, module docstring).

The store is a real SQLite file. Its connection is wrapped so that, when armed, the COMMIT of the
next batch waits for the test: the batch's rows are then written inside an open transaction but
not durable, so no ack may be out, not even to a resend of the same record arriving meanwhile
(the core's ``pend`` path). Released, the COMMIT either goes through or fails as a disk error
does. Every ack is also checked, at the moment it is sent, against another connection to the file.
No sleeps: every wait is on an event, with a generous deadline.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import sqlite3
import threading
from collections.abc import Callable, Hashable
from pathlib import Path

import pytest

from gateway import protocol as p
from gateway.ingest.core import IngestCore
from gateway.store import Store

KEY = hashlib.sha256(b"serra test key: device 7").digest()
OKV = (21.5, 65.0, 12.0, 80.0, 432.1, 3.4, 0.0)
DEADLINE = 30.0  # [s] for any single wait; a loaded machine still meets it
BOARD = ("192.0.2.7", 5683)  # the peer that first sends each record
RESENDER = ("192.0.2.8", 5683)  # the same board's resend, seen from another source
STORED = p.ACK_STORED


def pkt(seq: int, boot: int = 1) -> bytes:
    return p.encode_record(p.Record(7, boot, seq, 1000 * seq, 5, 60.0, OKV, (0,) * 7), KEY)


class CommitGate:
    """A store connection whose next COMMIT, once ``armed``, waits for ``release``; then it
    commits, or with ``fail`` rolls back and raises the OperationalError of a disk error (SQLite
    rolls back a transaction whose commit hit an I/O error). Anything else is passed through."""

    def __init__(self, conn: sqlite3.Connection, loop: asyncio.AbstractEventLoop) -> None:
        self._conn = conn
        self._loop = loop
        self.armed = False
        self.fail: str | None = None  # "io" or "busy": how the released COMMIT fails
        self.entered = asyncio.Event()  # set (on the loop) when an armed COMMIT is waiting
        self.release = threading.Event()

    def __getattr__(self, name: str) -> object:
        return getattr(self._conn, name)

    def execute(self, sql: str, *args: object) -> sqlite3.Cursor:
        if sql == "COMMIT" and self.armed:
            self.armed = False
            self._loop.call_soon_threadsafe(self.entered.set)
            if not self.release.wait(DEADLINE):
                self._conn.execute("ROLLBACK")
                raise sqlite3.OperationalError("test gate: never released")
            if self.fail == "io":  # SQLite rolls back a transaction whose commit hit an I/O error
                self._conn.execute("ROLLBACK")
                raise sqlite3.OperationalError("disk I/O error")
            if self.fail == "busy":  # SQLITE_BUSY on COMMIT leaves the transaction open
                raise sqlite3.OperationalError("database is locked")
        return self._conn.execute(sql, *args)


class Acks:
    """The ``send`` callback of one peer: every ack it was sent, decoded, with whether the
    record's row was visible to another connection to the store at that moment."""

    def __init__(self, reader: sqlite3.Connection) -> None:
        self.reader = reader
        self.got: list[tuple[int, int, bool]] = []  # (seq, status, row visible when sent)

    def __call__(self, data: bytes, peer: Hashable) -> None:
        a = p.decode_ack(data, KEY)
        visible = self.reader.execute("SELECT count(*) FROM samples WHERE device_id=? AND "
                                      "boot=? AND seq=?", (a.device_id, a.boot, a.seq)
                                      ).fetchone()[0] == 1
        self.got.append((a.seq, a.status, visible))


class Rig:
    """IngestCore on a real store file with a CommitGate, its writer running as in the service;
    ``committed`` counts records made durable (``on_commit``), ``errors`` the ERROR log lines."""

    def __init__(self, tmp: Path) -> None:
        self.db = tmp / "g.db"

    async def __aenter__(self) -> Rig:
        loop = asyncio.get_running_loop()
        self.store = Store(self.db)
        self.gate = CommitGate(self.store.conn, loop)
        self.store.conn = self.gate  # type: ignore[assignment]
        self.committed = 0
        self._commit_seen = asyncio.Event()
        self.core = IngestCore(self.store, {7: KEY}, on_commit=self._on_commit)
        self.errors: list[logging.LogRecord] = []
        self._error_seen = asyncio.Event()
        self._handler = _Collect(self.errors, lambda: loop.call_soon_threadsafe(
            self._error_seen.set))
        logging.getLogger("serra.ingest").addHandler(self._handler)
        self.reader = sqlite3.connect(f"{self.db.as_uri()}?mode=ro", uri=True,
                                     isolation_level=None)
        self.board, self.resender = Acks(self.reader), Acks(self.reader)
        self.writer = asyncio.create_task(self.core.run_writer())
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.gate.release.set()  # a failed test must not leave the store thread waiting
        self.writer.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self.writer
        self.core.close()
        self.store.close()
        self.reader.close()
        logging.getLogger("serra.ingest").removeHandler(self._handler)

    def _on_commit(self, n: int) -> None:
        self.committed += n
        self._commit_seen.set()

    def send(self, seq: int, *, resend: bool = False) -> None:
        """One packet of record ``seq`` arriving, as a transport hands it over."""
        if resend:
            self.core.handle(pkt(seq), RESENDER, self.resender)
        else:
            self.core.handle(pkt(seq), BOARD, self.board)

    async def until_committed(self, total: int) -> None:
        while self.committed < total:
            await asyncio.wait_for(self._commit_seen.wait(), DEADLINE)
            self._commit_seen.clear()

    async def until_error_logged(self) -> None:
        await asyncio.wait_for(self._error_seen.wait(), DEADLINE)

    def rows(self) -> list[tuple[int, int, int]]:
        """(boot, seq, copies) of every stored sample, read through another connection."""
        return self.reader.execute("SELECT boot, seq, count(*) FROM samples GROUP BY boot, seq "
                                   "ORDER BY boot, seq").fetchall()


class _Collect(logging.Handler):
    """Keeps the ERROR records of a logger and calls ``on_record`` after each."""

    def __init__(self, into: list[logging.LogRecord], on_record: Callable[[], None]) -> None:
        super().__init__(logging.ERROR)
        self.into, self.on_record = into, on_record

    def emit(self, record: logging.LogRecord) -> None:
        self.into.append(record)
        self.on_record()



def test_no_ack_while_the_commit_is_held_not_even_to_a_resend(tmp_path: Path) -> None:
    async def go() -> None:
        async with Rig(tmp_path) as r:
            r.gate.armed = True
            for s in range(4):  # one batch: the writer runs only once this coroutine yields
                r.send(s)
            await asyncio.wait_for(r.gate.entered.wait(), DEADLINE)
            # The batch is written inside its transaction, its COMMIT held: not durable yet.
            assert r.gate.in_transaction and r.rows() == []
            assert r.board.got == [], "acked before its batch committed"
            r.send(2, resend=True)  # a resend of a record of the held batch: waits for it
            assert r.resender.got == [], "a resend during the commit was acked before it"
            assert r.core.counters["duplicate"] == 1
            r.send(4)  # a new record: queued for the next batch
            assert r.board.got == [] and r.rows() == []

            r.gate.release.set()
            await r.until_committed(5)
            # Each packet acked once, STORED, and its row was in the file when the ack went out.
            assert sorted(r.board.got) == [(s, STORED, True) for s in range(5)]
            assert r.resender.got == [(2, STORED, True)]
            assert r.rows() == [(1, s, 1) for s in range(5)]
            assert r.core.counters["stored"] == 5 and r.errors == []

    asyncio.run(go())


@pytest.mark.parametrize("fail, why", [("io", "disk I/O error"), ("busy", "database is locked")])
def test_a_failed_commit_acks_nothing_loses_nothing_and_the_resends_are_stored_once(
        tmp_path: Path, fail: str, why: str) -> None:
    """Whether SQLite rolled the failed COMMIT back (an I/O error) or left it open (busy: the
    store then rolls it back, db.transaction), the store takes the resends afterwards."""
    async def go() -> None:
        async with Rig(tmp_path) as r:
            for s in range(3):
                r.send(s)
            await r.until_committed(3)
            assert sorted(r.board.got) == [(s, STORED, True) for s in range(3)]

            r.gate.armed, r.gate.fail = True, fail
            for s in range(3, 6):
                r.send(s)
            await asyncio.wait_for(r.gate.entered.wait(), DEADLINE)
            r.send(4, resend=True)  # waits on the batch that is about to fail
            r.gate.release.set()
            await r.until_error_logged()
            # The store was refused the batch: not one ack for it, to the board nor the resend.
            assert sorted(r.board.got) == [(s, STORED, True) for s in range(3)]
            assert r.resender.got == []
            [err] = r.errors
            assert err.name == "serra.ingest" and err.levelno == logging.ERROR
            assert err.getMessage() == (f"store write of 3 records failed (device 7 seq 3-5): "
                                        f"{why}; none acknowledged, the boards keep them and "
                                        f"resend")
            assert r.core.counters["store_error"] == 3 and r.core.counters["stored"] == 3
            # What was committed before is all there; nothing of the failed batch is.
            assert r.rows() == [(1, s, 1) for s in range(3)]

            # The store works again; the board resends what it holds unacknowledged.
            for s in range(3, 6):
                r.send(s)
            r.send(4, resend=True)  # the other source's resend lands in the same batch
            await r.until_committed(6)
            assert sorted(r.board.got) == [(s, STORED, True) for s in range(6)]
            assert r.resender.got == [(4, STORED, True)]
            assert r.rows() == [(1, s, 1) for s in range(6)]
            assert r.core.counters["stored"] == 6 and len(r.errors) == 1

    asyncio.run(go())


def test_the_shutdown_drain_waits_for_the_commit_in_flight_and_its_acks(tmp_path: Path) -> None:
    """serve()'s stop drains, then closes the transports: a drain that found the queue empty
    because the writer had just taken it returned at once, the transports were closed, and the
    writer's acks of a batch it committed a moment later were never sent (the board resent
    records already stored to the next start). The drain now waits for that commit and its
    acks. (The test releases the COMMIT only once the drain has run: a drain that does not wait
    is already done then.)"""
    async def go() -> None:
        async with Rig(tmp_path) as r:
            r.gate.armed = True
            r.send(0)
            await asyncio.wait_for(r.gate.entered.wait(), DEADLINE)  # the writer took the queue
            drain = asyncio.create_task(r.core.drain())
            for _ in range(3):
                await asyncio.sleep(0)
            r.gate.release.set()
            await asyncio.wait_for(drain, DEADLINE)
            assert r.board.got == [(0, STORED, True)], "the drain did not wait for the commit"

    asyncio.run(go())

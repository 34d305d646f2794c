"""Store: batching writer, device state, keys file, aggregates with QC, outbox, retention."""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

import pytest

from gateway.protocol import CHANNELS, ST_OK, ST_PARTIAL, ST_TIMEOUT, Record
from gateway.store import Store, retention
from gateway.store import aggregate as agg
from gateway.store.keys import KeyFileError, load_keys, parse_keys, write_keys
from gateway.store.outbox import Message, Outbox, OutboxFull

T0 = 1_700_000_000.0 // 60 * 60  # a minute boundary
OKV = (21.5, 65.0, 12.0, 80.0, 432.1, 3.4, 0.0)


def rec(seq: int, dev: int = 7, boot: int = 1, values=OKV, status=(ST_OK,) * 7,
        age_ms: int = 0) -> Record:
    return Record(dev, boot, seq, seq * 10_000, age_ms, 10.0, tuple(values), tuple(status))


def test_write_batch_durable_and_idempotent(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    assert s.conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert s.write_batch([(rec(i), T0 + i) for i in range(5)]) == 5
    # Re-writing the same records stores nothing twice.
    assert s.write_batch([(rec(i), T0 + 10 + i) for i in range(3, 7)]) == 2
    assert s.conn.execute("SELECT count(*) FROM samples").fetchone()[0] == 7
    assert s.device_states()[7].max_seq == 6
    assert s.stored_seqs(7, 1, 4) == {5, 6}
    s.close()
    # Reopened: everything is there (real file, committed).
    s2 = Store(tmp_path / "g.db")
    row = s2.conn.execute("SELECT t_in, t_in_st, t, t_recv FROM samples WHERE seq=2").fetchone()
    assert row == (21.5, 0, T0 + 2, T0 + 2)
    assert s2.integrity_ok()


def test_wall_time_is_reception_minus_age(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    s.write_batch([(rec(0, age_ms=90_500), T0 + 100)])
    assert s.conn.execute("SELECT t FROM samples").fetchone()[0] == pytest.approx(T0 + 9.5)


def test_device_state_follows_new_boot_not_old(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    s.write_batch([(rec(50, boot=1), T0), (rec(3, boot=2), T0 + 1)])
    assert s.device_states()[7] == (2, 3)
    s.write_batch([(rec(60, boot=1), T0 + 2)])  # an old boot must not move the state back
    assert s.device_states()[7] == (2, 3)
    s.write_batch([(rec(9, boot=2), T0 + 3), (rec(1, boot=3), T0 + 4)])
    assert s.device_states()[7] == (3, 1)


def test_missing_values_stored_as_null_with_code(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    vals = (None, None, 12.0, 80.0, 0.0, 0.0, 1.0)
    s.write_batch([(rec(0, values=vals, status=(ST_TIMEOUT, ST_TIMEOUT) + (ST_OK,) * 5), T0)])
    assert s.conn.execute("SELECT t_in, t_in_st, rain FROM samples").fetchone() == (
        None, ST_TIMEOUT, 1.0)


def test_keys_file_permissions_and_errors(tmp_path: Path) -> None:
    p = tmp_path / "keys"
    k7, k9 = bytes.fromhex("5e" * 31 + "7a"), bytes.fromhex("a1b2" * 16)
    write_keys(p, {7: k7, 9: k9})
    assert load_keys(p) == {7: k7, 9: k9}
    os.chmod(p, 0o644)
    with pytest.raises(KeyFileError, match="chmod 600"):
        load_keys(p)
    with pytest.raises(KeyFileError, match=r"k:2: key of device 8 is not hexadecimal"):
        parse_keys("7 " + "00" * 32 + "\n8 zz\n", "k")
    with pytest.raises(KeyFileError, match=r"k:3: device 7 listed twice"):
        parse_keys("7 " + "00" * 32 + "\n# c\n7 " + "11" * 32, "k")
    with pytest.raises(KeyFileError, match=r"k:1: key of device 7 has 4 bytes"):
        parse_keys("7 00112233", "k")
    with pytest.raises(KeyFileError, match=r"k:1: device id 'x' is not an integer"):
        parse_keys("x 00", "k")


def _minute(s: Store, m: int, col: str):
    return s.conn.execute(f"SELECT {col}, {col}_qc, n FROM minute WHERE minute=?",
                          (int(T0) + 60 * m,)).fetchone()


def test_minute_aggregates_and_qc(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    # Minute 0: two good samples; minute 1: one partial, one timed-out t_in.
    s.write_batch([(rec(0, values=(20.0,) + OKV[1:]), T0 + 10),
                   (rec(1, values=(22.0,) + OKV[1:]), T0 + 40),
                   (rec(2, status=(ST_PARTIAL,) + (ST_OK,) * 6), T0 + 70),
                   (rec(3, values=(None,) + OKV[1:], status=(ST_TIMEOUT,) + (ST_OK,) * 6),
                    T0 + 100)])
    assert agg.aggregate(s.conn) == 2
    assert _minute(s, 0, "t_in") == (21.0, 0, 2)
    assert _minute(s, 1, "t_in") == (21.5, agg.QC_PARTIAL, 2)
    # Minute 2: only failed reads -> missing; minute 3: a 10 K jump -> spike.
    s.write_batch([(rec(4, values=(None,) + OKV[1:], status=(ST_TIMEOUT,) + (ST_OK,) * 6),
                    T0 + 130), (rec(5, values=(31.5,) + OKV[1:]), T0 + 150)])
    s.write_batch([(rec(6, values=(45.0,) + OKV[1:]), T0 + 190)])
    assert agg.aggregate(s.conn) == 2
    assert _minute(s, 2, "t_in") == (31.5, agg.QC_PARTIAL | agg.QC_SPIKE, 2)  # 10 K in 1 min
    assert _minute(s, 3, "t_in")[1] == agg.QC_SPIKE
    assert _minute(s, 3, "rh_in")[1] == 0
    # A late resend for minute 0 recomputes it.
    s.write_batch([(rec(7, values=(24.0,) + OKV[1:], age_ms=200_000), T0 + 250)])
    assert agg.aggregate(s.conn) == 1
    assert _minute(s, 0, "t_in") == (pytest.approx(22.0), 0, 3)
    assert agg.aggregate(s.conn) == 0


def test_qc_missing_and_stuck(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    miss = (None,) * 7
    s.write_batch([(rec(0, values=miss, status=(ST_TIMEOUT,) * 7), T0 + 5)])
    agg.aggregate(s.conn)
    for c in CHANNELS:
        assert _minute(s, 0, c)[1] & agg.QC_MISSING
    s.write_batch([(rec(i), T0 + 60 * i + 5) for i in range(1, agg.STUCK_MINUTES + 2)])
    agg.aggregate(s.conn)
    assert not _minute(s, agg.STUCK_MINUTES - 1, "t_in")[1] & agg.QC_STUCK
    assert _minute(s, agg.STUCK_MINUTES + 1, "t_in")[1] & agg.QC_STUCK
    assert not _minute(s, agg.STUCK_MINUTES + 1, "i_glob")[1] & agg.QC_STUCK


def test_outbox_bounded_with_alarm_never_drops(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    ob = Outbox(s.conn, max_rows=10, alarm_fraction=0.5)

    def msg(i: int) -> Message:
        return Message("serra/x", "k", float(i), f"m{i}", f"{i}")

    for i in range(4):
        ob.put(msg(i))
    assert not ob.alarm
    ob.put(msg(4))
    assert ob.alarm
    for i in range(5, 10):
        ob.put(msg(i))
    with pytest.raises(OutboxFull):  # full: refused, nothing dropped, the producer retries
        ob.put(msg(10))
    assert ob.pending() == 10 and ob.refused == 1
    batch = ob.peek(3)
    assert [m.payload for m in batch] == ["0", "1", "2"]
    ob.mark_sent([m.id for m in batch])
    assert ob.pending() == 7
    assert ob.put(msg(1)) == 0  # the same idempotency key is never added twice
    ob.put(msg(10))
    assert [m.payload for m in ob.peek(100)] == [str(i) for i in range(3, 11)]


def test_retention_and_capacity(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    s.write_batch([(rec(i), T0 - 86400 * 10 + i) for i in range(3)] +
                  [(rec(10 + i), T0 + i) for i in range(3)])
    s.add_estimates([(T0 - 86400 * 10, "online", "c_solar", 0.5, "1"),
                     (T0, "online", "c_solar", 0.6, "1")])
    pol = retention.Policy(samples_days=5, estimates_days=5)
    out = retention.apply(s.conn, pol, now=T0)
    assert out["samples"] == 3 and out["estimates"] == 1
    assert s.estimates("c_solar") == [(T0, "online", 0.6)]
    assert retention.capacity_alarms(tmp_path / "g.db", pol) == []
    tiny = retention.Policy(max_db_bytes=1000)
    assert "limit" in retention.capacity_alarms(tmp_path / "g.db", tiny)[0]


def test_retention_deletes_rejected_records_as_old_as_the_samples_it_deletes(tmp_path: Path) -> None:
    """The ``rejected`` table (records acknowledged as rejected) had no retention: a kit whose
    firmware sends an out-of-range record a minute would grow it without bound, for as long as
    the gateway runs. It is kept as long as the raw samples."""
    s = Store(tmp_path / "g.db")
    s.write_batch([(rec(i), T0 - 86400 * 10 + 60 * i) for i in range(3)] + [(rec(10), T0)])
    for seq, t in ((3, T0 - 86400 * 10 + 200), (4, T0 - 86400 * 10 + 260), (11, T0 - 60)):
        s.note_rejected(7, 1, seq, "out_of_range", t)
    out = retention.apply(s.conn, retention.Policy(samples_days=5), now=T0)
    assert out["samples"] == 3 and out["rejected"] == 2
    assert s.conn.execute("SELECT seq FROM rejected").fetchall() == [(11,)]
    s.close()


def test_aggregation_works_through_a_backlog_in_bounded_steps(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    s.write_batch([(rec(i), T0 + 60 * i + 1) for i in range(50)])
    steps = []
    while (n := agg.aggregate(s.conn, max_rows=7)) > 0:
        steps.append(n)
    assert steps == [7] * 7 + [1]
    assert s.conn.execute("SELECT count(*), sum(n) FROM minute").fetchone() == (50, 50)


class _CommitFails:
    """The store's connection, whose next COMMIT fails as SQLite's SQLITE_BUSY does: the error
    is raised and the transaction is left open (the COMMIT never ran)."""

    def __init__(self, conn) -> None:
        self._conn, self.armed = conn, True

    def execute(self, sql: str, *args):
        if self.armed and sql.strip().upper() == "COMMIT":
            self.armed = False
            raise sqlite3.OperationalError("database is locked")
        return self._conn.execute(sql, *args)

    def __getattr__(self, name: str):
        return getattr(self._conn, name)


def test_a_failed_commit_is_rolled_back_and_the_store_keeps_working(tmp_path: Path) -> None:
    """A COMMIT that fails and leaves the transaction open must not wedge the store: the batch
    is rolled back (nothing of it stored, the write lock released) and the next batch, the
    same records resent, is stored once."""
    s = Store(tmp_path / "g.db")
    assert s.write_batch([(rec(i), T0 + i) for i in range(3)]) == 3
    real = s.conn
    s.conn = _CommitFails(real)
    with pytest.raises(sqlite3.OperationalError, match="locked"):
        s.write_batch([(rec(i), T0 + i) for i in range(3, 6)])
    assert not real.in_transaction
    with sqlite3.connect(tmp_path / "g.db") as other:  # the write lock is free
        other.execute("BEGIN IMMEDIATE")
        assert other.execute("SELECT count(*) FROM samples").fetchone()[0] == 3
        other.execute("ROLLBACK")
    assert s.write_batch([(rec(i), T0 + i) for i in range(3, 6)]) == 3
    assert sorted(r[0] for r in real.execute("SELECT seq FROM samples")) == list(range(6))
    s.conn = real
    s.close()


def test_a_clean_close_leaves_no_wal_behind_even_with_a_reader_open(tmp_path: Path) -> None:
    """The gateway's last connection to close was a read-only one (the history queryable's), so
    SQLite's own checkpoint-on-close never ran and serra.db-wal stayed at ~4 MB after a clean
    stop. Store.close() checkpoints and truncates it, whatever readers are still open."""
    from gateway.store import open_readonly

    db, wal = tmp_path / "g.db", tmp_path / "g.db-wal"
    s = Store(db)
    for b in range(20):
        s.write_batch([(rec(100 * b + i), T0 + 100 * b + i) for i in range(100)])
    reader = open_readonly(db)  # idle, as the history queryable between queries
    try:
        assert reader.execute("SELECT count(*) FROM samples").fetchone()[0] == 2000
        assert wal.stat().st_size > 100_000  # the batches are in the WAL
        s.close()
        # SQLite deletes the -wal only when the last connection to close can write: with the
        # reader open it stays, empty (SQLite's TRUNCATE checkpoint: zero bytes)
        assert wal.stat().st_size == 0
        assert reader.execute("SELECT count(*) FROM samples").fetchone()[0] == 2000
    finally:
        reader.close()
    alone = sqlite3.connect(f"file:{db}?mode=ro&immutable=1", uri=True)  # the file, no WAL
    try:
        assert alone.execute("SELECT count(*) FROM samples").fetchone()[0] == 2000
    finally:
        alone.close()

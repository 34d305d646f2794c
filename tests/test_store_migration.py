"""Schema version 5: a version-1 store is migrated in place (to 2, 3, 4, then 5) and keeps every
row; a version-3 store gains the (empty) board health table (4); a version-3 or -4 store's
estimates are keyed by time and their newest rows kept apart (5); a new store and a migrated one
have the same tables; an unknown version is refused."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from gateway.protocol import CHANNELS
from gateway.status.store_source import StoreSource
from gateway.store import Store, StoreError, schema
from gateway.store.live import EstimateRow, add_estimates, latest_estimates
from gateway.store.outbox import Message, Outbox
from gateway.store.retention import Policy, apply

V1_TABLES = ("devices", "samples", "minute", "estimates", "outbox", "meta")


def make_v1(path: Path) -> None:
    """A version-1 file as a version-1 gateway left it, with rows in every table."""
    c = sqlite3.connect(path, isolation_level=None)
    c.executescript(schema.DDL_V1)
    c.execute("PRAGMA user_version = 1")
    chans = [x for ch in CHANNELS for x in (ch, f"{ch}_st")]
    c.execute("INSERT INTO devices VALUES (7, 2, 41, 1.7e9, 1.7e9 + 600, 42)")
    for seq in range(42):
        vals = [None if (seq + i) % 9 == 0 else 10.0 + seq / 7 + i for i in range(len(CHANNELS))]
        row = [7, 2, seq, 1.7e9 + 60 * seq, 1.7e9 + 60 * seq + 0.2, seq * 60_000, 60.0]
        for v in vals:
            row += [v, 0x11 if v is None else 0]
        c.execute(f"INSERT INTO samples (device_id, boot, seq, t, t_recv, tick_ms, period_s, "
                  f"{', '.join(chans)}) VALUES ({', '.join('?' * len(row))})", row)
    qc = [x for ch in CHANNELS for x in (ch, f"{ch}_qc")]
    for m in range(5):
        row = [7, 1.7e9 // 60 * 60 + 60 * m, 1] + [v for i in range(len(CHANNELS))
                                                   for v in (float(i + m), m % 3)]
        c.execute(f"INSERT INTO minute (device_id, minute, n, {', '.join(qc)}) "
                  f"VALUES ({', '.join('?' * len(row))})", row)
    c.executemany("INSERT INTO estimates (t, source, name, value, unit, info) VALUES (?,?,?,?,?,?)",
                  [(1.7e9 + i, "online", "c_solar", 1e-5 * i, "1", "") for i in range(6)])
    c.executemany("INSERT INTO outbox (created, key, payload, attempts, sent) VALUES (?,?,?,?,?)",
                  [(1.7e9 + i, "serra/a/b/x", f'{{"i": {i}}}', i % 2, None if i > 2 else 1.7e9)
                   for i in range(6)])
    c.execute("INSERT INTO meta VALUES ('agg_rowid', '40')")
    c.close()


def dump(path: Path) -> dict[str, list[tuple]]:
    with sqlite3.connect(path) as c:
        out = {}
        for t in V1_TABLES:
            cols = [r[1] for r in sqlite3.connect(path).execute(f"PRAGMA table_info({t})")]
            v1 = [x for x in cols if (t, x) not in {("estimates", "greenhouse"), ("outbox", "kind"),
                                                   ("outbox", "t"), ("outbox", "idem")}]
            out[t] = c.execute(f"SELECT {', '.join(v1)} FROM {t} ORDER BY rowid").fetchall()
        return out


def tables(path: Path) -> dict[str, list[tuple]]:
    with sqlite3.connect(path) as c:
        names = [r[0] for r in c.execute(
            "SELECT name FROM sqlite_master WHERE type IN ('table', 'index', 'trigger') ORDER BY name")]
        return {n: c.execute(f"PRAGMA index_info({n})").fetchall() or
                c.execute(f"PRAGMA table_info({n})").fetchall() for n in names}


def test_v1_store_migrates_keeping_every_row(tmp_path: Path) -> None:
    old = tmp_path / "v1.db"
    make_v1(old)
    before = dump(old)
    assert all(before[t] for t in V1_TABLES)
    s = Store(old)  # opening migrates
    assert s.conn.execute("PRAGMA user_version").fetchone()[0] == schema.SCHEMA_VERSION == 5
    assert s.integrity_ok()
    s.close()
    assert dump(old) == before  # every row of every version-1 table, unchanged
    with sqlite3.connect(old) as c:
        idem = [r[0] for r in c.execute("SELECT idem FROM outbox ORDER BY id")]
        assert idem == [f"v1:{i}" for i in range(1, 7)]
        assert c.execute("SELECT count(*) FROM outbox WHERE sent IS NULL").fetchone()[0] == 3
        # loss accounting starts at the latest boot's oldest stored seq (nothing counted)
        assert c.execute("SELECT device_id, boot, final_seq, lost, open_from FROM boot_losses"
                         ).fetchall() == [(7, 2, 0, 0, None)]
    # the migrated file has exactly the tables, columns and indexes of a new one
    new = tmp_path / "new.db"
    Store(new).close()
    assert tables(old) == tables(new)
    # and works as a current store: its unsent v1 messages come first, then new ones
    s = Store(old)
    ob = Outbox(s.conn)
    ob.put(Message("serra/a/b/forecast", "forecast", 1.7e9, "a/b/forecast/1", "{}"))
    assert [m.idem for m in ob.peek(10)] == ["v1:4", "v1:5", "v1:6", "a/b/forecast/1"]
    s.close()
    Store(old).close()  # opening a current store again changes nothing
    assert dump(old)["samples"] == before["samples"]


def test_v3_store_gains_the_health_table_keeping_every_row(tmp_path: Path) -> None:
    """Version 3 → 4 adds only ``board_health`` (empty), in its own step (then 4 → 5)."""
    old = tmp_path / "v3.db"
    make_v1(old)
    Store(old).close()
    with sqlite3.connect(old) as c:  # what a version-3 gateway left
        c.execute("DROP TABLE board_health")
        c.execute("PRAGMA user_version = 3")
    before = dump(old)
    s = Store(old)
    assert s.conn.execute("PRAGMA user_version").fetchone()[0] == schema.SCHEMA_VERSION
    assert s.conn.execute("SELECT count(*) FROM board_health").fetchone()[0] == 0
    s.close()
    assert dump(old) == before
    new = tmp_path / "new.db"
    Store(new).close()
    assert tables(old) == tables(new)


def make_old(path: Path, version: int = 4) -> list[tuple]:
    """A version-3 or -4 file as such a gateway left it (its own migrations, which stop there),
    with estimate rows of two greenhouses, minutes stored out of order; the rows, by id."""
    c = sqlite3.connect(path, isolation_level=None)
    c.executescript(schema.DDL_V1)
    schema.migrate_v1_v2(c)
    schema.migrate_v2_v3(c)
    if version == 4:
        schema.migrate_v3_v4(c)
    assert c.execute("PRAGMA user_version").fetchone()[0] == version
    rows = [(gh, 1.7e9 + 60 * m, src, name, m + 0.5 * i, unit, info)
            for m in (3, 1, 2, 0) for gh in ("north", "south")
            for i, (src, name, unit, info) in enumerate((
                ("measured", "t_in", "degC", ""), ("online", "c_loss", "W m-2 K-1", ""),
                ("forecast", "t_in+15min", "degC", "hold-latest")))]
    rows.append(("north", 1.7e9 - 600, "vsensor", "ventilation_flow", 0.4, "m3 s-1", "out_of_range"))
    c.executemany("INSERT INTO estimates (greenhouse, t, source, name, value, unit, info) "
                  "VALUES (?, ?, ?, ?, ?, ?, ?)", rows)
    out = c.execute("SELECT * FROM estimates ORDER BY id").fetchall()
    c.close()
    return out


@pytest.mark.parametrize("version", [3, 4])
def test_an_older_store_migrates_to_time_keyed_estimates(tmp_path: Path, version: int) -> None:
    old = tmp_path / f"v{version}.db"
    before = make_old(old, version)
    with sqlite3.connect(old) as c:
        idx = {r[0] for r in c.execute("SELECT name FROM sqlite_master WHERE type='index' "
                                       "AND tbl_name='estimates'")}
    assert idx == {"estimates_t", "estimates_gh"}
    s = Store(old)  # opening migrates
    assert s.conn.execute("PRAGMA user_version").fetchone()[0] == schema.SCHEMA_VERSION == 5
    assert s.integrity_ok()
    assert s.conn.execute("SELECT * FROM estimates ORDER BY id").fetchall() == before
    idx = {r[0] for r in s.conn.execute("SELECT name FROM sqlite_master WHERE type='index' "
                                        "AND tbl_name='estimates'")}
    assert idx == {"estimates_tgn"}
    newest = {}
    for _id, t, src, name, value, unit, info, gh in before:
        if (gh, name, src) not in newest or t > newest[(gh, name, src)][0]:
            newest[(gh, name, src)] = (t, value, unit, info)
    latest = "SELECT greenhouse, name, source, t, value, unit, info FROM estimates_latest"
    assert {r[:3]: r[3:] for r in s.conn.execute(latest)} == newest
    assert len(newest) == 7  # 3 names x 2 greenhouses + the ventilation row
    # the plans of the status screen's queries: a minute and a day by the time index
    plan = " ".join(r[3] for r in s.conn.execute(
        "EXPLAIN QUERY PLAN SELECT t, value FROM estimates WHERE greenhouse=? AND name=? AND t>?",
        ("north", "t_in", 1.7e9)))
    assert "estimates_tgn" in plan and "SCAN" not in plan
    # rows written after the migration keep the newest apart; an older one leaves it
    add_estimates(s.conn, [EstimateRow("north", 1.7e9 + 600, "online", "c_loss", 9.0, "W m-2 K-1"),
                           EstimateRow("south", 1.7e9 - 60, "online", "c_loss", -1.0, "x")])
    assert latest_estimates(s.conn, "north")[("online", "c_loss")].value == 9.0
    assert latest_estimates(s.conn, "south")[("online", "c_loss")].value == 3.5
    # retention prunes the newest rows with the rows: the ventilation row is the last of its name
    apply(s.conn, Policy(estimates_days=1.0), now=1.7e9 + 86400 - 300)
    assert ("vsensor", "ventilation_flow") not in latest_estimates(s.conn, "north")
    assert latest_estimates(s.conn, "north")[("online", "c_loss")].value == 9.0
    s.close()
    new = tmp_path / "new.db"
    Store(new).close()
    assert tables(old) == tables(new)




@pytest.mark.parametrize("version", [3, 4])
def test_status_refuses_a_store_older_than_5(tmp_path: Path, version: int) -> None:
    old = tmp_path / f"v{version}.db"
    make_old(old, version)
    with pytest.raises(StoreError, match=f"version {version}: start the gateway once"):
        StoreSource(old)


def test_unknown_schema_version_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "future.db"
    with sqlite3.connect(p) as c:
        c.execute("PRAGMA user_version = 9")
    with pytest.raises(RuntimeError, match="version 9"):
        Store(p)

"""``make run``'s progress line: its two message counts read from the real stores (the gateway's
outbox, the subscriber's cloud store) while both grow, never show more received than published."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

from gateway.cloud.store import Received, SqliteCloudStore
from gateway.store import Store
from gateway.store.outbox import Message, Outbox
from training.appliance.summary import EstimateCount, delivery, summarise


def test_received_never_reads_above_published_while_both_grow(tmp_path: Path) -> None:
    db, cloud = tmp_path / "serra.db", tmp_path / "cloud.db"
    gateway, sub = Store(db), SqliteCloudStore(cloud)
    outbox = Outbox(gateway.conn)
    total, stop = 400, threading.Event()

    def publish_then_receive() -> None:  # as the run does: put and marked sent, then stored
        for i in range(total):
            if stop.is_set():
                return
            m = Message("serra/f/north/status", "status", float(i), f"idem-{i}", "{}")
            outbox.put(m)
            outbox.mark_sent([r[0] for r in gateway.conn.execute(
                "SELECT id FROM outbox WHERE idem=?", (m.idem,))])
            sub.add([Received(m.key, m.payload, m.idem, "f", "north", m.kind, m.t, m.t)])

    writer = threading.Thread(target=publish_then_receive)
    reads = []
    try:
        writer.start()
        while writer.is_alive():
            reads.append(delivery(db, cloud))
    finally:
        stop.set()
        writer.join(60)
        gateway.close()
        sub.conn.close()
    moving = [r for r in reads if 0 < r[1] < total]
    assert moving, "no read while messages moved (the writer ran too fast to watch)"
    assert all(received <= published for published, received in reads), \
        [r for r in reads if r[1] > r[0]][:5]
    assert delivery(db, cloud) == (total, total)


def _whole_count(db: Path, where: str, args: tuple = ()) -> tuple[int, list[str]]:
    """A count over the whole ``estimates`` table, and its plan."""
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        sql = f"SELECT count(*) FROM estimates WHERE {where}"
        return (conn.execute(sql, args).fetchone()[0],
                [r[3] for r in conn.execute(f"EXPLAIN QUERY PLAN {sql}", args)])
    finally:
        conn.close()


def test_estimator_minutes_counted_as_they_come_equal_the_whole_count(tmp_path: Path) -> None:
    """The run's "minutes estimated" (progress line, settling, summary) read the whole v5 index
    at each call (``SCAN ... estimates_tgn``: it leads with t); counted by id as they come, the
    number is the same at every step of a real estimator filling a real store."""
    from gateway.service.pipeline import GreenhousePipeline
    from gateway.store.aggregate import aggregate
    from gateway.store.live import save_greenhouses
    from tests.status_store import EPOCH, GH, MODEL, gh_config, records

    db = tmp_path / "serra.db"
    counted = EstimateCount(db, "north", "t_in_next")
    assert counted() == 0  # no store yet
    s = Store(db)
    try:
        save_greenhouses(s.conn, [gh_config()], EPOCH)
        pipe = GreenhousePipeline("north", GH, MODEL, 7, 7, None, seed=1)
        pipe.resume(s.conn)
        seen = []
        for first, last in ((0, 40), (40, 41), (41, 90)):
            s.write_batch(records(7, range(first, last)))
            while aggregate(s.conn):
                pass
            pipe.step_pending(s.conn, EPOCH + 60 * last + 31, 0.0, 600.0)
            whole, plan = _whole_count(db, "greenhouse=? AND name=?", ("north", "t_in_next"))
            seen.append((counted(), whole))
            assert any(p.startswith("SCAN") for p in plan), plan  # what the count was
    finally:
        s.close()
    assert [c for c, _ in seen] == [w for _, w in seen] and seen[-1][0] > seen[0][0] > 0
    assert counted() == seen[-1][0]  # nothing new: nothing added
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        plan = [r[3] for r in conn.execute("EXPLAIN QUERY PLAN " + EstimateCount.SQL,
                                           ("north", "t_in_next", 0))]
        assert plan == ["SEARCH estimates USING INTEGER PRIMARY KEY (rowid>?)"]
        names = sorted(n for (n,) in conn.execute(
            "SELECT DISTINCT name FROM estimates WHERE greenhouse='north' AND source='forecast'"))
    finally:
        conn.close()
    # the summary's forecast horizons, from estimates_latest: those of the whole table
    summary = summarise(db, tmp_path / "cloud.db", 0, EPOCH, EPOCH + 5400, 1.0, "north", 7,
                        counted())
    assert names and [f"t_in+{k.horizon_min}min" for k in summary.skill] == sorted(
        names, key=lambda n: int(n[5:-3]))
    assert summary.estimated == seen[-1][0]

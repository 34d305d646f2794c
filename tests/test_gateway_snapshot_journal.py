"""The estimator's snapshot saved every ``snapshot_every_min`` minutes, a journal of the minutes
stepped since it in between (gateway/service/pipeline.py): stepped live, one batch a minute, on
a real SQLite file, a gateway restarted in the middle of a journal makes the same rows as one
never stopped, bit for bit, and none twice; the snapshot is not rewritten between its saves."""

from __future__ import annotations

from pathlib import Path

from gateway.service.pipeline import GreenhousePipeline
from gateway.store import Store
from gateway.store.live import load_journal
from tests.test_gateway_pipeline import EPOCH, GH, MODEL, end, fill, rows

EVERY = 15  # [min] the default (EstimatorSettings.snapshot_every_min)


def pipeline(outside: int = 7) -> GreenhousePipeline:
    pl = GreenhousePipeline("north", GH, MODEL, 7, outside, None, seed=1,
                            snapshot_every_min=EVERY)
    return pl


def live(store: Store, pl: GreenhousePipeline, ks: range, *, skip: frozenset[int] = frozenset(),
         outside_late: frozenset[int] = frozenset(), max_wait_s: float = 600.0) -> None:
    """As live: the kit sends minute k (not those in ``skip``; an outside kit 8 sends it unless
    it is in ``outside_late``), then the gateway steps what is final: minute k − 1."""
    for k in ks:
        if k not in skip:
            fill(store, range(k, k + 1))
        if pl.outside != pl.inside and k not in outside_late:
            fill(store, range(k, k + 1), device=8)
        pl.step_pending(store.conn, end(k), 0.0, max_wait_s)


def duplicates(store: Store) -> int:
    return store.conn.execute("SELECT count(*) FROM (SELECT 1 FROM estimates GROUP BY t, source, "
                              "name HAVING count(*) > 1)").fetchone()[0]


def saved(store: Store) -> tuple[int, str]:
    return store.conn.execute("SELECT minute, state FROM estimator_state").fetchone()


def test_a_restart_mid_journal_makes_the_rows_of_a_run_never_stopped(tmp_path: Path) -> None:
    hole = frozenset({33, 34})  # the kit sent nothing: stepped as missing minutes, journaled
    whole = Store(tmp_path / "whole.db")
    pa = pipeline()
    pa.resume(whole.conn)
    live(whole, pa, range(0, 33), skip=hole)
    at32 = saved(whole)
    live(whole, pa, range(33, 46), skip=hole)
    at44 = saved(whole)
    # the snapshot of minute 30 is not rewritten until minute 45; the cursor follows each batch
    assert (at32[0], at44[0]) == (EPOCH + 60 * 31, EPOCH + 60 * 44) and at32[1] == at44[1]
    journal = load_journal(whole.conn, "north")
    assert journal is not None and journal.snapshot == EPOCH + 60 * 30
    assert [m for m, _ in journal.minutes] == [EPOCH + 60 * k for k in (31, 32, *range(35, 45))]
    live(whole, pa, range(46, 70), skip=hole)

    split = Store(tmp_path / "split.db")
    first = pipeline()
    first.resume(split.conn)
    live(split, first, range(0, 40), skip=hole)  # stops at minute 38: 6 minutes journaled
    second = pipeline()  # a restarted gateway
    line = second.resume(split.conn)
    assert "resumed at" in line and "6 minutes stepped again" in line, line
    assert second.cursor == EPOCH + 60 * 38
    live(split, second, range(40, 47))  # stops at minute 45, just after a snapshot
    assert load_journal(split.conn, "north") is None  # the snapshot is the whole state
    third = pipeline()
    assert "stepped again" not in third.resume(split.conn)
    live(split, third, range(47, 70))
    assert rows(split) == rows(whole) and len(rows(whole)) > 60 * len(MODEL.names)
    assert duplicates(split) == 0
    assert saved(split) == saved(whole)


def test_the_journal_keeps_what_was_stepped_when_a_late_kit_changes_the_minutes(
        tmp_path: Path) -> None:
    """The outside kit's records of minutes 31–36 arrive after those minutes were stepped
    without them (``max_wait_s`` 0): the restart steps them again as they were stepped, from
    the journal, not as the store now holds them."""
    late = frozenset(range(31, 37))
    whole = Store(tmp_path / "whole.db")
    pa = pipeline(outside=8)
    pa.resume(whole.conn)
    live(whole, pa, range(0, 38), outside_late=late, max_wait_s=0.0)
    fill(whole, range(31, 37), device=8)  # the lagging kit sends them now
    live(whole, pa, range(38, 60), max_wait_s=0.0)

    split = Store(tmp_path / "split.db")
    first = pipeline(outside=8)
    first.resume(split.conn)
    live(split, first, range(0, 38), outside_late=late, max_wait_s=0.0)
    fill(split, range(31, 37), device=8)
    n = split.conn.execute("SELECT count(*) FROM minute WHERE device_id=8 AND minute>=? AND "
                           "minute<?", (EPOCH + 60 * 31, EPOCH + 60 * 37)).fetchone()[0]
    assert n == 6  # the store's minutes are no longer those stepped
    second = pipeline(outside=8)
    assert "stepped again" in second.resume(split.conn)
    live(split, second, range(38, 60), max_wait_s=0.0)
    assert rows(split) == rows(whole) and duplicates(split) == 0

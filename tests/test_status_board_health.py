"""A kit's own counters (its latest health packet, store table board_health) on the status
screen's kits panel, from the store and from the device message, beside the losses the gateway
infers; and in the device message, valid against the shipped Device schema."""

from __future__ import annotations

import json
import sqlite3

from gateway import protocol as p
from gateway.publish import payloads as P
from gateway.publish import validate as V
from gateway.status import render
from gateway.status.messages import Messages
from gateway.status.snapshot import Link
from gateway.store import Store
from gateway.store.board_health import board_fields, latest
from gateway.store.live import set_status
from tests.status_helpers import fresh_status, snap_of
from tests.status_store import Filled

HEALTH = p.BoardHealth(7, 0, 5, -67, 7260, 400, 150, 2, 500, 240, 0, 3, 40960, 8)


def test_the_boards_own_drops_show_beside_the_inferred_count(store: Filled) -> None:
    s = Store(store.path)
    try:
        s.note_health(HEALTH, 0, store.now - 30)  # as ingest keeps it
        report = latest(s.conn)[7]
    finally:
        s.close()
    want = ("     board says ({}): 152 dropped from its ring this boot (full 150, too old 2) · "
            "3 send errors · wifi -67 dBm · heap 40 kB free · up 2 h 1 min")
    lines = [t.plain for t in render.kit_lines(snap_of(store))]
    at = [i for i, x in enumerate(lines) if "board says" in x]
    assert len(at) == 1 and all(len(x) <= render.WIDTH for x in lines), lines
    told = " ".join(" ".join(lines[at[0]:at[0] + 2]).split())  # wrapped on two lines
    hhmm = told.split("(")[1].split(")")[0]
    assert told == " ".join(want.format(hhmm).split()), lines
    assert lines[at[0] - 1].startswith("     all 7 channels ok")  # under kit 7's line
    # The same through Zenoh: the device message the gateway publishes, read back.
    doc = P.device("f1", 7, store.now, "d7", state="ok", boot=0, records=400, lost=0,
                   last_seen=store.now, channels={}, greenhouses=[],
                   board=board_fields(report, 0, 0))
    assert V.errors(json.loads(P.dumps(doc))) == []
    assert doc["recordsDroppedOnBoard"]["value"] == 152 and doc["rssi"]["value"] == -67
    assert doc["boardCounters"]["value"]["droppedRingFull"] == 150
    m = Messages()
    assert m.add("serra/f1/north/device/7", json.dumps(doc))
    kit = next(k for k in m.snapshot("z", store.now, True, Link(True, True, "")).kits
               if k.device_id == 7)
    assert kit.board is not None and kit.board.dropped == 152
    from_store = next(k for k in snap_of(store).kits if k.device_id == 7).board
    assert kit.board == from_store


def test_health_packets_taken_are_not_rejected_packets(store: Filled) -> None:
    beat = fresh_status(store)
    s = Store(store.path)
    try:
        set_status(s.conn, {"ingest": {"stored": 120, "health": 4, "health_replay": 1}},
                   store.now)
    finally:
        s.close()
    assert snap_of(store, wall=beat).gateway.rejects == {"health_replay": 1}


def test_a_store_without_the_health_table_reads_as_no_reports() -> None:
    """A read-only reader may open a version-3 store, which has no board_health."""
    with sqlite3.connect(":memory:") as c:
        assert latest(c) == {}

"""Health packets (wire type 0x03) through the real ingest service over UDP on 127.0.0.1: the
latest per device is stored, never acknowledged; a tampered, replayed, stale or inconsistent one
is refused and counted by reason; records flow exactly as before around them."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from gateway import protocol as p
from tests.mcu_fakes.hostenv import micropython, run_mpy
from tests.test_ingest import KEY, Gateway, pkt, run, until


def health(hseq: int, boot: int = 1, dropped_full: int = 3, **kw: int | None) -> p.BoardHealth:
    f: dict[str, int | None] = dict(
        device_id=7, boot=boot, hseq=hseq, rssi_dbm=-61, uptime_s=60 * (hseq + 1),
        records=40, dropped_full=dropped_full, dropped_old=1, sent=50, acked=30, rejected=1,
        send_errors=2, heap_free=41000, ring=40 - 30 - 1 - dropped_full - 1)
    f.update(kw)
    return p.BoardHealth(**f)  # type: ignore[arg-type]


def row(db: Path) -> tuple | None:
    with sqlite3.connect(db) as c:
        return c.execute("SELECT boot, hseq, records, dropped_full, dropped_old, rssi_dbm "
                         "FROM board_health WHERE device_id = 7").fetchone()


def test_roundtrip_and_what_an_old_gateway_makes_of_it() -> None:
    h = health(4, rssi_dbm=None)
    data = p.encode_health(h, KEY)
    assert len(data) == p.HEALTH_LEN == 72 and p.is_health(data)
    p.verify_health(data, KEY)
    assert p.parse_health(data) == h
    # A version-1 gateway without this type checks the length first: refused as `long`,
    # unanswered, before any crypto (the board neither waits for nor resends health packets).
    with pytest.raises(p.ProtocolError) as e:
        p.peek_device(data)
    assert e.value.reason == "long"


MPY_HEALTH = """
import sys, binascii, wire
buf = bytearray(wire.HEALTH_LEN)
for hseq, rssi in ((4, -61), (5, -128)):
    wire.seal_health(buf, wire.Hmac(binascii.unhexlify(sys.argv[1])), 7, 1, hseq, rssi,
                     [240, 40, 3, 1, 50, 30, 1, 2, 41000, 5])
    print(binascii.hexlify(buf).decode())
"""


@pytest.mark.skipif(micropython() is None, reason="micropython interpreter not installed")
def test_the_firmware_builds_the_same_bytes(tmp_path: Path) -> None:
    """mcu/wire.py (under the real MicroPython) and gateway/protocol.py: one byte layout."""
    script = tmp_path / "health_mpy.py"
    script.write_text(MPY_HEALTH)
    r = run_mpy(script, KEY.hex(), timeout=60)
    assert r.returncode == 0, r.stderr
    want = [p.encode_health(health(4, uptime_s=240), KEY).hex(),
            p.encode_health(health(5, uptime_s=240, rssi_dbm=None), KEY).hex()]
    assert r.stdout.split() == want
    assert p.parse_health(bytes.fromhex(want[1])).rssi_dbm is None


def test_health_is_stored_and_refused_when_tampered_replayed_or_inconsistent(
        tmp_path: Path) -> None:
    async def first() -> None:
        async with Gateway(tmp_path) as g:
            c = g.core.counters
            assert p.decode_ack(await g.exchange(pkt(0)), KEY).status == p.ACK_STORED
            latest = p.encode_health(health(1), KEY)
            assert await g.exchange(latest, expect_reply=False) is None  # never acknowledged
            await until(lambda: row(g.db) is not None, "health stored")
            assert row(g.db) == (1, 1, 40, 3, 1, -61)
            # The records around it are stored and acknowledged as before.
            assert p.decode_ack(await g.exchange(pkt(1)), KEY).status == p.ACK_STORED
            assert p.decode_ack(await g.exchange(pkt(1)), KEY).status == p.ACK_DUPLICATE
            tampered = bytearray(p.encode_health(health(2), KEY))
            tampered[33] ^= 0x40  # dropped_old: 1 -> 65
            stale = p.encode_health(health(0, dropped_full=0), KEY)  # older than #1
            bad = p.encode_health(health(3, ring=99), KEY)  # does not add up
            other = p.encode_health(health(2, boot=0), KEY)  # a boot older than the records'
            for data in (bytes(tampered), latest, stale, bad, other,
                         p.encode_health(health(2, device_id=8), KEY)):
                assert await g.exchange(data, expect_reply=False) is None
            await until(lambda: c["unknown_device"] == 1, "all refused")
            assert (c["bad_tag"], c["health_replay"], c["malformed"], c["health"]) == (1, 3, 1, 1)
            assert c["stored"] == 2 and c["duplicate"] == 1
            assert row(g.db) == (1, 1, 40, 3, 1, -61)  # none of them replaced the latest
            await g.exchange(p.encode_health(health(2, dropped_full=4), KEY), expect_reply=False)
            await until(lambda: c["health"] == 2, "the next health packet taken")

    async def second() -> None:  # the replay state comes back from the store
        async with Gateway(tmp_path) as g:
            await g.exchange(p.encode_health(health(2, dropped_full=4), KEY), expect_reply=False)
            await g.exchange(p.encode_health(health(0, boot=2, rssi_dbm=None), KEY),
                             expect_reply=False)  # a new boot starts again at #0
            await until(lambda: g.core.counters["health"] == 1, "new boot's health taken")
            assert g.core.counters["health_replay"] == 1
            await until(lambda: (row(g.db) or (0,))[0] == 2, "stored")
            assert row(g.db) == (2, 0, 40, 3, 1, None)

    run(first())
    assert row(tmp_path / "g.db") == (1, 2, 40, 4, 1, -61)
    run(second())

"""Records lost on the board, inferred from the sequence numbers (gateway/store/losses.py): the
real ingest service over UDP on 127.0.0.1 with its SQLite store. A period of 6553.5 s (the
longest the wire carries) makes the board's ring drop a record 41 records later (2**28 ms), so
short runs reach the point where a gap is final."""

from __future__ import annotations

import logging
import random
import sqlite3
from pathlib import Path

import pytest

from gateway import protocol as p
from gateway.store import losses
from tests.mcu_fakes.hostenv import micropython, run_mpy
from tests.test_ingest import KEY, OKV, Gateway, run

PERIOD_S = 6553.5
SPAN = losses.span_records(65535)


def pkt(seq: int, boot: int = 1, values=OKV) -> bytes:
    return p.encode_record(p.Record(7, boot, seq, 1000 * seq, 5, PERIOD_S, tuple(values),
                                    (0,) * 7), KEY)


def lost(db: Path) -> dict[int, tuple[int, int]]:
    """boot → (final_seq, lost) of device 7."""
    with sqlite3.connect(db) as c:
        return {b: (f, n) for b, f, n in c.execute(
            "SELECT boot, final_seq, lost FROM boot_losses WHERE device_id = 7")}


RING_SCRIPT = """
import sys
from time import ticks_add, ticks_ms
from ring import Ring
period, cap, n = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
r = Ring(cap)
t0 = ticks_ms()
for s in range(n):
    r.push(s, ticks_add(t0, s * period))
    print(s, min(x for x in r.seq if x >= 0))
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
@pytest.mark.parametrize("period_ds, cap", [(600, 1024), (6000, 1024), (65535, 120)],
                         ids=["60 s", "10 min", "6553.5 s"])
def test_the_span_is_where_the_firmware_ring_lets_go(period_ds: int, cap: int,
                                                      tmp_path: Path) -> None:
    """The real mcu/ring.py under MicroPython (the board's clock), nothing acknowledged, a ring
    too big to fill before the span: after record S the oldest it holds is exactly
    S − span + 1, span = span_records(period): what a gap's finality rests on."""
    script = tmp_path / "ring_span.py"
    script.write_text(RING_SCRIPT)
    span = losses.span_records(period_ds)
    assert span == {600: 512, 6000: (1 << 28) // 600_000 + 1, 65535: 41}[period_ds]
    r = run_mpy(script, str(period_ds * 100), str(cap), str(span + 40), cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    oldest = dict(tuple(map(int, line.split())) for line in r.stdout.splitlines())
    assert oldest == {s: max(0, s - span + 1) for s in range(span + 40)}


def test_gaps_are_counted_once_when_final_not_before(tmp_path: Path,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    """Holes 10–19 and 25 never sent, seq 30 rejected (out of range), every other record sent
    twice and shuffled within blocks of 8 (resends and reordering as the radio makes them):
    only the holes are counted, each once, and only once the newest seq is a span above them;
    a late arrival of a counted record takes it off; a restart of the gateway and a new boot of
    the board add nothing."""
    caplog.set_level(logging.WARNING, "serra.ingest")
    holes = set(range(10, 20)) | {25}
    hot = list(OKV)
    hot[0] = 95.0  # t_in above 80 °C: out_of_range, acked as rejected
    rng = random.Random(5)
    seqs = [s for s in range(120) if s not in holes]

    async def first() -> None:
        async with Gateway(tmp_path) as g:
            for i in range(0, len(seqs), 8):
                block = seqs[i:i + 8] * 2
                rng.shuffle(block)
                for s in block:
                    a = p.decode_ack(await g.exchange(pkt(s, values=hot if s == 30 else OKV)),
                                     KEY)
                    assert a.status == (p.ACK_REJECTED if s == 30 else
                                        p.ACK_STORED if a.status == p.ACK_STORED else
                                        p.ACK_DUPLICATE)
                    top = max(x for x in seqs[:i + 8])
                    # never counted before final: nothing below top - SPAN is missing yet
                    n = g.core.counters["lost_on_board"]
                    assert n <= len([h for h in holes if h <= top - SPAN]), (s, n)
            assert g.core.counters["lost_on_board"] == 11
            assert lost(g.db) == {1: (119 - SPAN + 1, 11)}
            # a record counted lost that arrives after all (held in the network) is taken off
            assert p.decode_ack(await g.exchange(pkt(12)), KEY).status == p.ACK_STORED
            assert g.core.counters["lost_on_board"] == 10
            assert lost(g.db)[1] == (119 - SPAN + 1, 10)

    async def second() -> None:
        async with Gateway(tmp_path) as g:  # restarted: the state is the store's
            assert p.decode_ack(await g.exchange(pkt(100)), KEY).status == p.ACK_DUPLICATE
            assert p.decode_ack(await g.exchange(pkt(120)), KEY).status == p.ACK_STORED
            # the board restarts (boot 2, seq 0): boot 1 is settled up to its newest seq, 120,
            # and every seq of it is there; seqs it had made above 120 are unknowable
            assert p.decode_ack(await g.exchange(pkt(0, boot=2)), KEY).status == p.ACK_STORED
            assert lost(g.db) == {1: (121, 10)}  # boot 2: nothing settled yet
            assert g.core.counters["lost_on_board"] == 0
            assert losses.lost_by_device(g.core.store.conn) == {7: 10}

    run(first())
    run(second())
    msgs = [r.getMessage() for r in caplog.records if "device 7 boot 1: record" in
            r.getMessage()]
    assert ("device 7 boot 1: records 10–19 lost on the board (dropped from its ring: overflow "
            "or too old)") in msgs
    assert ("device 7 boot 1: record 25 lost on the board (dropped from its ring: overflow or "
            "too old)") in msgs
    assert ("device 7 boot 1: record 12 arrived after being counted lost: no longer counted"
            in msgs)
    assert len(msgs) == 3, msgs


def test_a_restart_makes_the_gaps_below_its_last_record_final(tmp_path: Path,
                                                              caplog: pytest.LogCaptureFixture
                                                              ) -> None:
    """Seqs 3 and 5–6 of boot 1 missing, the newest 8 (far below a span): not final until the
    board's next boot, then counted as lost at its restart, once."""
    caplog.set_level(logging.WARNING, "serra.ingest")

    async def go() -> None:
        async with Gateway(tmp_path) as g:
            for s in (0, 1, 2, 4, 7, 8):
                assert p.decode_ack(await g.exchange(pkt(s)), KEY).status == p.ACK_STORED
            assert g.core.counters["lost_on_board"] == 0
            for s in (0, 1):
                assert p.decode_ack(await g.exchange(pkt(s, boot=2)), KEY).status == p.ACK_STORED
            assert g.core.counters["lost_on_board"] == 3
            assert lost(g.db) == {1: (9, 3)}

    run(go())
    msgs = [r.getMessage() for r in caplog.records if "lost on the board" in r.getMessage()]
    assert msgs == ["device 7 boot 1: records 3, 5–6 lost on the board (it restarted before "
                    "they were stored)"]


def test_a_long_gap_is_counted_as_it_becomes_final_and_logged_once_whole(tmp_path: Path) -> None:
    """Seqs 10–54 missing: each is counted when the span passes it, the gap is reported once,
    when the record above it settles, across a restart of the store (the writer's state is in
    boot_losses)."""
    from gateway.store import Store

    def recs(seqs) -> list[tuple[p.Record, float]]:
        return [(p.Record(7, 1, s, 1000 * s, 5, PERIOD_S, OKV, (0,) * 7), 1.7e9 + s)
                for s in seqs]

    s = Store(tmp_path / "g.db")
    first = losses.Report()
    s.write_batch(recs(range(10)), first)
    s.write_batch(recs([55]), first)  # final up to 55 - SPAN: 10–14 lost, the run still open
    s.close()
    assert (first.lost, first.gaps) == (5, [])
    assert lost(tmp_path / "g.db") == {1: (55 - SPAN + 1, 5)}
    s = Store(tmp_path / "g.db")
    then = losses.Report()
    s.write_batch(recs(range(56, 101)), then)
    s.close()
    assert then.lost == 40
    assert then.gaps == [losses.Gap(7, 1, 10, 54, losses.RING)]
    assert lost(tmp_path / "g.db") == {1: (100 - SPAN + 1, 45)}

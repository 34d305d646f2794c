"""Ingest service in-process over real UDP on 127.0.0.1 and a real pty: validation, counters,
acks only after commit, replay protection across restarts, COBS framing."""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import socket
import sqlite3
import tty
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import protocol as p
from gateway.ingest import service
from gateway.ingest.counters import RateLimitedLog
from gateway.ingest.framing import Deframer, FramingError, cobs_decode, cobs_encode
from gateway.store.keys import set_key, write_keys

KEY = hashlib.sha256(b"serra test key: device 7").digest()
OTHER = hashlib.sha256(b"serra test key: device 9").digest()
OKV = (21.5, 65.0, 12.0, 80.0, 432.1, 3.4, 0.0)


def rec(seq: int, boot: int = 1, dev: int = 7, values=OKV, status=(0,) * 7) -> p.Record:
    return p.Record(dev, boot, seq, 1000 * seq, 5, 60.0, tuple(values), tuple(status))


def pkt(seq: int, boot: int = 1, **kw) -> bytes:
    return p.encode_record(rec(seq, boot, **kw), KEY)


class Gateway:
    """serve() in the test's event loop, with a UDP client socket."""

    def __init__(self, tmp: Path, serial_url: str | None = None, udp: bool = True) -> None:
        self.keys = tmp / "keys"
        write_keys(self.keys, {7: KEY, 9: OTHER})
        self.db = tmp / "g.db"
        self.cfg = service.IngestConfig(db=self.db, keys=self.keys,
                                        listen=("127.0.0.1", 0) if udp else None,
                                        serial=serial_url, maintenance_every=0.2)
        self.cli = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cli.setblocking(False)

    async def __aenter__(self) -> Gateway:
        ready = asyncio.Event()

        def on_ready(r: service.Running) -> None:
            self.core, self.addr = r.core, r.udp_address
            ready.set()

        self.task = asyncio.ensure_future(service.serve(self.cfg, on_ready))
        await asyncio.wait_for(ready.wait(), 10)
        return self

    async def __aexit__(self, *exc) -> None:
        self.task.cancel()
        try:
            await self.task
        except asyncio.CancelledError:
            pass
        self.cli.close()

    async def exchange(self, data: bytes, expect_reply: bool = True) -> bytes | None:
        loop = asyncio.get_running_loop()
        await loop.sock_sendto(self.cli, data, self.addr)
        if not expect_reply:
            await asyncio.sleep(0.05)
            return None
        return await asyncio.wait_for(loop.sock_recv(self.cli, 256), 10)


def run(coro):
    return asyncio.run(coro)


def test_accepts_acks_after_commit_and_counts_every_reason(tmp_path: Path) -> None:
    async def go() -> None:
        async with Gateway(tmp_path) as g:
            a = p.decode_ack(await g.exchange(pkt(0)), KEY)
            assert (a.seq, a.status) == (0, p.ACK_STORED)
            # Durable before the ack: another connection already sees the row.
            with sqlite3.connect(g.db) as c:
                assert c.execute("SELECT count(*) FROM samples").fetchone()[0] == 1
            a = p.decode_ack(await g.exchange(pkt(0)), KEY)
            assert a.status == p.ACK_DUPLICATE
            a = p.decode_ack(await g.exchange(pkt(5)), KEY)
            assert a.status == p.ACK_STORED
            bad = bytearray(pkt(6))
            bad[-1] ^= 1
            for data in (b"", b"SR", pkt(6) + b"x", b"XX" + pkt(6)[2:], bytes(bad),
                         p.encode_record(rec(1, dev=8), KEY),
                         p.encode_record(rec(1, dev=9), KEY)):  # device 9 has another key
                assert await g.exchange(data, expect_reply=False) is None
            # Authenticated but out of range: a final, authenticated rejection.
            a = p.decode_ack(await g.exchange(pkt(7, values=(99.0,) + OKV[1:])), KEY)
            assert (a.status, a.reason) == (p.ACK_REJECTED, p.REASON_CODES["out_of_range"])
            # New boot, then the old boot is a replay.
            assert p.decode_ack(await g.exchange(pkt(0, boot=2)), KEY).status == p.ACK_STORED
            assert await g.exchange(pkt(8, boot=1), expect_reply=False) is None
            # Far below the window of the current boot: replay.
            for s in (2000, 1000):
                assert p.decode_ack(await g.exchange(pkt(s, boot=2)), KEY).status == 0
            assert await g.exchange(pkt(500, boot=2), expect_reply=False) is None
            c = g.core.counters
            assert c["stored"] == 5 and c["duplicate"] == 1
            for reason in ("short", "long", "bad_magic", "bad_tag", "unknown_device",
                           "out_of_range", "replay_old_boot", "replay_old_seq"):
                assert c[reason] >= 1, reason
            assert c["short"] == 2

    run(go())
    with sqlite3.connect(tmp_path / "g.db") as c:
        rows = c.execute("SELECT boot, seq FROM samples ORDER BY boot, seq").fetchall()
    assert rows == [(1, 0), (1, 5), (2, 0), (2, 1000), (2, 2000)]


def test_restart_keeps_replay_state_and_reacks_duplicates(tmp_path: Path) -> None:
    async def first() -> None:
        async with Gateway(tmp_path) as g:
            for s in range(10):
                assert p.decode_ack(await g.exchange(pkt(s, boot=3)), KEY).status == 0

    async def second() -> None:
        async with Gateway(tmp_path) as g:
            assert p.decode_ack(await g.exchange(pkt(4, boot=3)), KEY).status == p.ACK_DUPLICATE
            assert await g.exchange(pkt(4, boot=2), expect_reply=False) is None
            assert p.decode_ack(await g.exchange(pkt(10, boot=3)), KEY).status == p.ACK_STORED
            assert g.core.counters["replay_old_boot"] == 1

    run(first())
    run(second())


async def until(cond, what: str, timeout: float = 30.0) -> None:
    """Wait (on the event loop, not blocking it) until ``cond()`` holds; a generous deadline."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not cond():
        if loop.time() > end:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.02)


def test_keys_file_is_read_again_while_running(tmp_path: Path,
                                               caplog: pytest.LogCaptureFixture) -> None:
    """Adding, rotating and removing a device take effect without a restart; a broken file
    is logged and the keys in use stay."""
    new8 = hashlib.sha256(b"serra test key: device 8").digest()
    new7 = hashlib.sha256(b"serra test key: device 7, reflashed").digest()

    async def go() -> None:
        async with Gateway(tmp_path) as g:
            c = g.core.counters
            assert p.decode_ack(await g.exchange(pkt(0, boot=4)), KEY).status == p.ACK_STORED
            await g.exchange(p.encode_record(rec(0, dev=8), new8), expect_reply=False)
            await until(lambda: c["unknown_device"] == 1, "device 8 refused")

            set_key(g.keys, 8, new8)  # added
            await until(lambda: 8 in g.core.devs, "device 8 taken")
            a = p.decode_ack(await g.exchange(p.encode_record(rec(0, dev=8), new8)), new8)
            assert (a.device_id, a.status) == (8, p.ACK_STORED)

            set_key(g.keys, 7, new7, rotate=True)  # reflashed board: boot counter back at 0
            await until(lambda: g.core.keys[7] == new7, "device 7's new key taken")
            await g.exchange(pkt(1, boot=4), expect_reply=False)  # the old key's packets
            await until(lambda: c["bad_tag"] == 1, "the old key refused")
            a = p.decode_ack(await g.exchange(p.encode_record(rec(0, boot=0), new7)), new7)
            assert (a.boot, a.seq, a.status) == (0, 0, p.ACK_STORED)

            with caplog.at_level(logging.ERROR, logger="serra.ingest"):
                g.keys.write_text("7 zz\n")  # a typo while editing
                await until(lambda: "not taken" in caplog.text, "the broken file logged")
            assert f"{g.keys}:1" in caplog.text
            a = p.decode_ack(await g.exchange(p.encode_record(rec(1, dev=8), new8)), new8)
            assert a.status == p.ACK_STORED  # the keys in use stayed

            write_keys(g.keys, {7: new7, 8: new8})  # device 9 removed
            await until(lambda: 9 not in g.core.devs, "device 9 removed")
            await g.exchange(p.encode_record(rec(0, dev=9), OTHER), expect_reply=False)
            await until(lambda: c["unknown_device"] == 2, "device 9 refused")

    run(go())
    with sqlite3.connect(tmp_path / "g.db") as conn:
        rows = conn.execute("SELECT device_id, boot, seq FROM samples ORDER BY device_id, boot, "
                            "seq").fetchall()
    assert rows == [(7, 4, 0), (7, 5, 0), (8, 1, 0), (8, 1, 1)]  # new key: above the old boots


def test_minute_aggregates_are_computed_by_the_service(tmp_path: Path) -> None:
    async def go() -> None:
        async with Gateway(tmp_path) as g:
            for s in range(3):
                await g.exchange(pkt(s))
            def counted() -> bool:
                c = sqlite3.connect(g.db)
                try:
                    return c.execute("SELECT sum(n) FROM minute").fetchone()[0] == 3
                finally:
                    c.close()

            await until(counted, "the minute aggregates of 3 packets", timeout=60.0)

    run(go())


def test_serial_transport_over_a_real_pty(tmp_path: Path) -> None:
    master, slave = os.openpty()
    tty.setraw(master)
    url = os.ttyname(slave)

    async def go() -> None:
        async with Gateway(tmp_path, serial_url=url, udp=False) as g:
            loop = asyncio.get_running_loop()
            deframer = Deframer()
            # Line noise, then a garbage frame, then real frames split across writes.
            os.write(master, b"\x05\x01\x02\x00")
            frames = b"".join(cobs_encode(pkt(s)) + b"\0" for s in range(3))
            os.write(master, frames[:40])
            os.write(master, frames[40:])
            got: list[p.Ack] = []
            deadline = loop.time() + 15
            while len(got) < 3 and loop.time() < deadline:
                data = await loop.run_in_executor(None, os.read, master, 256)
                for f in deframer.feed(data):
                    assert not isinstance(f, FramingError)
                    got.append(p.decode_ack(f, KEY))
            assert sorted(a.seq for a in got) == [0, 1, 2]
            assert g.core.counters["framing"] == 1 and g.core.counters["stored"] == 3
    try:
        run(go())
    finally:
        os.close(master)
        os.close(slave)
    with sqlite3.connect(tmp_path / "g.db") as c:
        assert c.execute("SELECT count(*) FROM samples").fetchone()[0] == 3


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_cobs_roundtrip(data: bytes) -> None:
    enc = cobs_encode(data)
    assert b"\0" not in enc
    assert cobs_decode(enc) == data
    frames = Deframer(max_frame=1000).feed(enc + b"\0" + enc + b"\0")
    assert frames == [data, data]


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_deframer_never_raises(data: bytes) -> None:
    for f in Deframer(max_frame=100).feed(data):
        assert isinstance(f, bytes | FramingError)


def test_rate_limited_log(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    rl = RateLimitedLog(logging.getLogger("t"), interval=10, burst=3, clock=lambda: now[0])
    with caplog.at_level(logging.WARNING):
        emitted = [rl.warning("bad_tag", "bad %d", i) for i in range(10)]
        now[0] = 11.0
        rl.warning("bad_tag", "bad again")
    assert emitted == [True] * 3 + [False] * 7
    assert "7 more 'bad_tag' messages suppressed" in caplog.text


def test_service_refuses_world_readable_keys(tmp_path: Path, capsys) -> None:
    k = tmp_path / "keys"
    write_keys(k, {7: KEY})
    os.chmod(k, 0o644)
    rc = service.main(["--db", str(tmp_path / "g.db"), "--keys", str(k),
                       "--listen", "127.0.0.1:0"])
    assert rc == os.EX_CONFIG  # 78: the unit does not restart on a wrong keys file
    assert "chmod 600" in capsys.readouterr().err


_FUZZ: dict = {}


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=120),
                          st.builds(lambda i, x: bytes(b ^ x if j == i else b
                                                       for j, b in enumerate(pkt(3))),
                                    st.integers(0, p.RECORD_LEN - 1), st.integers(1, 255))),
                max_size=20))
def test_core_never_crashes_nor_acks_forgeries(tmp_path_factory, datagrams: list[bytes]) -> None:
    from gateway.ingest.core import IngestCore
    from gateway.store import Store

    if "core" not in _FUZZ:  # one store for all examples: nothing forged may ever reach it
        _FUZZ["core"] = IngestCore(Store(tmp_path_factory.mktemp("fz") / "g.db"), {7: KEY})
    core = _FUZZ["core"]
    replies: list[bytes] = []
    for d in datagrams:
        core.handle(d, ("127.0.0.1", 9), lambda pkt, peer: replies.append(pkt))
    assert core.counters["internal_error"] == 0
    assert not core._pending  # nothing forged was queued for storage
    for r in replies:  # only authenticated content problems are answered
        assert p.decode_ack(r, KEY).status == p.ACK_REJECTED


def test_service_reports_bad_arguments_clearly(tmp_path: Path, capsys) -> None:
    k = tmp_path / "keys"
    write_keys(k, {7: KEY})
    assert service.main(["--db", str(tmp_path / "no" / "g.db"), "--keys", str(k)]) == 2
    assert "cannot open the store" in capsys.readouterr().err
    assert service.main(["--db", str(tmp_path / "g.db"), "--keys", str(tmp_path / "none")]) == os.EX_CONFIG
    assert "No such file" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        service.main(["--db", "x", "--keys", str(k), "--listen", "nope"])
    assert "expected HOST:PORT, got 'nope'" in capsys.readouterr().err


def test_ingest_help_through_the_gateway_cli(capsys) -> None:
    from gateway.cli import main

    with pytest.raises(SystemExit) as e:
        main(["ingest", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: python -m gateway ingest")
    assert "--retention-days" in out and "example:" in out

"""Issue 8: the five field faults an independent attacker found in ingest, keys and export.

Each test failed on the code before the fix. Real UDP on 127.0.0.1 (OS-chosen ports), real
SQLite files, the real CLI in a subprocess where the whole stderr matters.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import socket
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from gateway import protocol as p
from gateway.ingest import service
from gateway.store.keys import write_keys
from tests.test_ingest import Gateway as IngestGateway

ROOT = Path(__file__).resolve().parents[1]
KEY_A = hashlib.sha256(b"serra test: board 7, first key").digest()
KEY_B = hashlib.sha256(b"serra test: board 7, after the reflash").digest()
KEY_9 = hashlib.sha256(b"serra test: board 9").digest()


def pkt(seq: int, boot: int, key: bytes, t_in: float = 21.5, dev: int = 7) -> bytes:
    rec = p.Record(dev, boot, seq, 1000 * seq, 5, 60.0, (t_in, 65.0, 12.0, 80.0, 432.1, 3.4, 0.0),
                   (0,) * 7)
    return p.encode_record(rec, key)


class Gateway(IngestGateway):
    """test_ingest's in-process gateway on given store and keys files, with helpers that wait
    for an answer rather than for time."""

    def __init__(self, db: Path, keys: Path) -> None:  # not super(): it writes its own keys
        self.cfg = service.IngestConfig(db=db, keys=keys, listen=("127.0.0.1", 0),
                                        maintenance_every=3600)
        self.cli = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cli.setblocking(False)

    async def replies(self, packets: list[bytes], marker: bytes, key: bytes) -> list[p.Ack]:
        """Send `packets`, then `marker` (a packet that is answered); return the answers that
        came before the marker's. The server handles one socket's datagrams in order, so the
        marker's answer means every packet before it was handled: no sleep, no guess."""
        loop = asyncio.get_running_loop()
        mark = p.peek_device(marker), int.from_bytes(marker[8:12], "big"), \
            int.from_bytes(marker[12:16], "big")
        for data in [*packets, marker]:
            await loop.sock_sendto(self.cli, data, self.addr)
        got: list[p.Ack] = []
        while True:
            a = p.decode_ack(await asyncio.wait_for(loop.sock_recv(self.cli, 256), 30), key)
            if (a.device_id, a.boot, a.seq) == mark:
                return got
            got.append(a)

    async def ack(self, data: bytes, key: bytes) -> p.Ack:
        loop = asyncio.get_running_loop()
        await loop.sock_sendto(self.cli, data, self.addr)
        return p.decode_ack(await asyncio.wait_for(loop.sock_recv(self.cli, 256), 30), key)


def samples(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as c:
        return c.execute("SELECT boot, seq, t_in FROM samples ORDER BY boot, seq").fetchall()


# -- 1. a reflashed board ---------------------------------------------------------------------

def test_reflashed_board_is_refused_by_name_then_rekeyed_without_loss_or_replay(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    db, keys = tmp_path / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY_A})

    async def before_reflash() -> None:
        async with Gateway(db, keys) as g:
            for boot in (0, 1):
                for s in range(3):
                    assert (await g.ack(pkt(s, boot, KEY_A), KEY_A)).status == p.ACK_STORED

    async def reflashed_same_key() -> None:
        # The flash lost its boot counter: the board starts again at boot 0.
        async with Gateway(db, keys) as g:
            with caplog.at_level(logging.WARNING, logger="serra.ingest"):
                got = await g.replies([pkt(s, 0, KEY_A, 30.0) for s in range(3)],
                                      marker=pkt(2, 1, KEY_A), key=KEY_A)
            assert got == []  # refused: no ack, the board keeps its records
            refused = [r.getMessage() for r in caplog.records if "device 7 refused" in
                       r.getMessage()]
            assert len(refused) == 1, caplog.text  # one line, not one per packet
            line = refused[0]
            assert "replay_old_boot" in line and "boot 0" in line, line
            assert f"python -m gateway keys rotate 7 --keys {keys}" in line, line
            r = g.core.refused[7]
            assert (r.reason, r.count, r.boot) == ("replay_old_boot", 3, 0)
            assert g.core.counters["replay_old_boot"] == 3

    async def rekeyed() -> None:
        async with Gateway(db, keys) as g:
            for s in range(3):  # the same (boot, seq) as stored rows: no collision, no loss
                a = await g.ack(pkt(s, 0, KEY_B, 30.0), KEY_B)
                assert (a.boot, a.seq, a.status) == (0, s, p.ACK_STORED)
            # Old packets replayed: the old key no longer authenticates anything.
            assert await g.replies([pkt(0, 1, KEY_A), pkt(5, 9, KEY_A)],
                                   marker=pkt(1, 0, KEY_B, 30.0), key=KEY_B) == []
            assert g.core.counters["bad_tag"] == 2
            assert g.core.counters["duplicate"] == 1

    async def restarted() -> None:
        async with Gateway(db, keys) as g:  # the new key keeps its place across restarts
            assert (await g.ack(pkt(2, 0, KEY_B, 30.0), KEY_B)).status == p.ACK_DUPLICATE
            assert (await g.ack(pkt(3, 0, KEY_B, 30.0), KEY_B)).status == p.ACK_STORED

    asyncio.run(before_reflash())
    asyncio.run(reflashed_same_key())
    write_keys(keys, {7: KEY_B})  # what `python -m gateway keys rotate 7` does (test_cli_keys)
    asyncio.run(rekeyed())
    asyncio.run(restarted())
    rows = samples(db)
    old = [r for r in rows if r[2] == 21.5]
    new = [r for r in rows if r[2] == 30.0]
    assert [r[:2] for r in old] == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]
    assert [r[1] for r in new] == [0, 1, 2, 3] and min(r[0] for r in new) > 1
    assert len({r[0] for r in new}) == 1  # one boot of the new key, above every old boot


# -- 2. a keys file that is not UTF-8 ----------------------------------------------------------

def gateway_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_non_utf8_keys_file_is_one_line_naming_file_and_line(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    write_keys(keys, {7: KEY_A})
    with open(keys, "ab") as f:
        f.write(b"# caf\xe9 greenhouse\n")
    r = gateway_cli("ingest", "--db", str(tmp_path / "g.db"), "--keys", str(keys),
                    "--listen", "127.0.0.1:0")
    assert r.returncode == os.EX_CONFIG, r.stderr  # 78: a wrong keys file, not restarted
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert f"{keys}:2:" in lines[0] and "UTF-8" in lines[0], lines[0]


# -- 3. an address that cannot be bound --------------------------------------------------------

def test_port_in_use_is_one_line_naming_address_and_port(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    write_keys(keys, {7: KEY_A})
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        r = gateway_cli("ingest", "--db", str(tmp_path / "g.db"), "--keys", str(keys),
                        "--listen", f"127.0.0.1:{port}")
    finally:
        taken.close()
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        f"error: cannot listen on 127.0.0.1:{port}: address already in use"], r.stderr


def test_serial_port_that_cannot_be_opened_is_one_line(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys"
    write_keys(keys, {7: KEY_A})
    assert service.main(["--db", str(tmp_path / "g.db"), "--keys", str(keys), "--serial",
                         str(tmp_path / "ttyUSB9")]) == 2
    assert capsys.readouterr().err == (f"error: cannot open serial port {tmp_path}/ttyUSB9: "
                                       "no such file or directory\n")


def test_listen_address_is_never_resolved(tmp_path: Path, monkeypatch) -> None:
    import argparse

    def no_dns(*a, **k):  # getaddrinfo without AI_NUMERICHOST would be a name look-up
        if not k.get("flags", 0) & socket.AI_NUMERICHOST:
            raise AssertionError(f"name resolution attempted: {a}")
        return real(*a, **k)

    real = socket.getaddrinfo
    monkeypatch.setattr(socket, "getaddrinfo", no_dns)
    with pytest.raises(argparse.ArgumentTypeError, match="not an IP address"):
        service.parse_hostport("gateway.example:5683")
    assert service.parse_hostport("[::1]:5683") == ("::1", 5683)
    assert service.parse_hostport(":5683") == ("0.0.0.0", 5683)

    keys = tmp_path / "keys"
    write_keys(keys, {7: KEY_A})
    cfg = service.IngestConfig(db=tmp_path / "g.db", keys=keys, listen=("gw.example", 0))
    with pytest.raises(service.ListenError, match=r"cannot listen on gw\.example:0: not an IP"):
        asyncio.run(service.serve(cfg))


# -- 4. readers change nothing -------------------------------------------------------------------

def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_export_refuses_a_file_that_is_not_a_serra_store_and_changes_nothing(
        tmp_path: Path, capsys) -> None:
    from gateway.cli import main

    empty = tmp_path / "empty.db"
    empty.touch()
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as c:  # another program's database
        c.execute("CREATE TABLE notes (id INTEGER PRIMARY KEY, text TEXT)")
        c.execute("INSERT INTO notes (text) VALUES ('tomatoes')")
    text = tmp_path / "notes.txt"
    text.write_text("not a database\n" * 200)
    for path, why in ((empty, "empty file"), (other, "not a Serra store"),
                      (text, "not an SQLite database")):
        before, listing = digest(path), sorted(os.listdir(tmp_path))
        assert main(["export", "--db", str(path), "--out", str(tmp_path / "x.csv")]) == 2
        err = capsys.readouterr().err
        assert str(path) in err and why in err, err
        assert digest(path) == before and sorted(os.listdir(tmp_path)) == listing
    # The writer too refuses another program's database instead of adding its tables to it.
    before = digest(other)
    keys = tmp_path / "keys"
    write_keys(keys, {7: KEY_A})
    assert service.main(["--db", str(other), "--keys", str(keys), "--listen", "127.0.0.1:0"]) == 2
    assert "a database of another program (tables notes)" in capsys.readouterr().err
    assert digest(other) == before
    with sqlite3.connect(other) as c:
        assert c.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
        assert c.execute("PRAGMA user_version").fetchone()[0] == 0
        assert [r[0] for r in c.execute("SELECT name FROM sqlite_master")] == ["notes"]


def test_export_reads_a_store_read_only_and_still_includes_unaggregated_samples(
        tmp_path: Path, capsys) -> None:
    from gateway.cli import main
    from gateway.store import Store

    db = tmp_path / "g.db"
    t0 = 1_700_000_000 // 60 * 60
    store = Store(db)
    store.write_batch([(p.Record(7, 1, s, s * 60_000, 0, 60.0, (20.0 + s / 10, 65.0, 12.0, 80.0,
                                                                  432.1, 3.4, 0.0), (0,) * 7),
                        float(t0 + 60 * s + 30)) for s in range(5)])
    store.close()
    before = digest(db)
    assert main(["export", "--db", str(db), "--out", str(tmp_path / "k.csv"), "--json"]) == 0
    assert '"rows": 5' in capsys.readouterr().out  # the newest samples are in the export
    assert digest(db) == before  # no aggregate, no bookkeeping written by a reader
    with sqlite3.connect(db) as c:
        assert c.execute("SELECT count(*) FROM minute").fetchone()[0] == 0


def test_open_readonly_is_the_readers_door(tmp_path: Path) -> None:
    from gateway.store import Store, StoreError, open_readonly

    db = tmp_path / "g.db"
    Store(db).close()
    conn = open_readonly(db)
    try:
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            conn.execute("INSERT INTO meta (name, value) VALUES ('x', 'y')")
    finally:
        conn.close()
    with pytest.raises(StoreError, match="no such store"):
        open_readonly(tmp_path / "missing.db")
    assert not (tmp_path / "missing.db").exists()


# -- 5. smaller points ---------------------------------------------------------------------------

def test_published_example_key_and_all_zero_key_are_refused(tmp_path: Path) -> None:
    from gateway.store.keys import KeyFileError, parse_keys

    example = (ROOT / "images" / "gateway" / "keys.example.txt").read_text()
    with pytest.raises(KeyFileError, match=r"ex:2: .*device 7.*published example key.*"
                                           r"python -m gateway keys"):
        parse_keys(example, "ex")
    with pytest.raises(KeyFileError, match=r"k:1: .*device 3.*python -m gateway keys"):
        parse_keys("3 " + "00" * 32, "k")


def test_empty_keys_file_is_a_warning_naming_the_file(tmp_path: Path,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    keys = tmp_path / "keys"
    write_keys(keys, {})

    async def go() -> None:
        with caplog.at_level(logging.INFO, logger="serra.ingest"):
            async with Gateway(tmp_path / "g.db", keys):
                pass

    asyncio.run(go())
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(str(keys) in w and "no device" in w for w in warnings), caplog.text


def test_keys_path_that_is_a_directory_is_named_as_such(tmp_path: Path) -> None:
    from gateway.store.keys import KeyFileError, load_keys

    d = tmp_path / "keys.d"
    d.mkdir(mode=0o755)
    os.chmod(d, 0o755)
    with pytest.raises(KeyFileError) as e:
        load_keys(d)
    assert "is a directory" in str(e.value) and "chmod" not in str(e.value), str(e.value)


def test_store_is_created_owner_only_under_the_default_umask(tmp_path: Path) -> None:
    from gateway.store import Store

    old = os.umask(0o022)
    try:
        s = Store(tmp_path / "g.db")
        s.write_batch([(p.Record(7, 1, 0, 0, 0, 60.0, (21.5, 65.0, 12.0, 80.0, 432.1, 3.4, 0.0),
                                 (0,) * 7), 1_700_000_000.0)])
        files = [f for f in tmp_path.iterdir() if f.name.startswith("g.db")]
        modes = {f.name: oct(f.stat().st_mode & 0o777) for f in files}
        s.close()
    finally:
        os.umask(old)
    assert len(files) == 3, modes  # the store, its WAL and its shared-memory index
    assert set(modes.values()) == {"0o600"}, modes


def test_a_flood_of_bad_tags_does_not_hide_a_real_device_with_a_wrong_key(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    from gateway.ingest.core import IngestCore
    from gateway.ingest.counters import RateLimitedLog
    from gateway.store import Store

    core = IngestCore(Store(tmp_path / "g.db"), {7: KEY_A, 9: KEY_9})
    try:
        core.rlog = RateLimitedLog(logging.getLogger("serra.ingest"), clock=lambda: 0.0)
        with caplog.at_level(logging.WARNING, logger="serra.ingest"):
            for s in range(200):  # forged packets for device 9, all in one 10-s window
                core.handle(pkt(s, 1, KEY_A, dev=9), ("127.0.0.1", 9), lambda *a: None)
            # then the real board 7, flashed with a wrong key
            core.handle(pkt(0, 1, KEY_B), ("127.0.0.1", 7), lambda *a: None)
        assert any("bad_tag" in r.getMessage() and "device 7" in r.getMessage()
                   for r in caplog.records), caplog.text
        assert core.counters["bad_tag"] == 201
    finally:
        core.close()
        core.store.close()


def test_log_limit_keeps_a_bounded_number_of_keys() -> None:
    from gateway.ingest.counters import RateLimitedLog

    now = [0.0]
    rl = RateLimitedLog(logging.getLogger("t"), clock=lambda: now[0])
    for dev in range(20_000):  # random device ids: one window each would grow without bound
        rl.warning("unknown_device", "device %d", dev, device=dev)
    assert len(rl._win) <= rl.max_keys + 1
    now[0] = 11.0  # the windows have run out: a new device gets its own again
    assert rl.warning("bad_tag", "device 7", device=7)
    assert ("bad_tag", " for device 7") in rl._win and len(rl._win) <= rl.max_keys + 1

"""Gateway killed with SIGKILL mid-stream and restarted 20 times: no acknowledged sample lost,
no duplicates, integrity_check ok. The sender behaves like the firmware (window of unacked
records, resends)."""

from __future__ import annotations

import hashlib
import os
import random
import select
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from gateway import protocol as p
from gateway.store.keys import write_keys

ROOT = Path(__file__).resolve().parents[1]
KEY = hashlib.sha256(b"serra test key: device 7").digest()
N = 30000
RATE = 3000  # records/s while the gateway is being killed (a busy fleet, not a flood)
WINDOW = 96


def values(seq: int) -> tuple[float, ...]:
    return (15 + (seq % 1000) / 100, 50 + seq % 40, 5.0, 70.0, float(seq % 900), 2.5, seq % 2)


def packet(seq: int) -> bytes:
    r = p.Record(7, 4, seq, seq * 60_000, 0, 60.0, values(seq), (0,) * 7)
    return p.encode_record(r, KEY)


def start_gateway(db: Path, keys: Path) -> tuple[subprocess.Popen, tuple[str, int]]:
    log = open(db.parent / "gateway.log", "a")  # noqa: SIM115 - kept by the child process
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys", str(keys),
         "--listen", "127.0.0.1:0", "--maintenance-every", "0.3"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=log, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 60)
    assert ready, "gateway did not start"
    line = proc.stdout.readline()
    assert line.startswith("serra-ingest listening udp"), line
    host, port = line.split()[-1].rsplit(":", 1)
    return proc, (host, int(port))


class Sender:
    """Window of unacknowledged records, resent after a timeout, like the firmware ring."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.next = 0
        self.unacked: dict[int, float] = {}
        self.acked: set[int] = set()
        self.dup_acks = 0

    def pump(self, addr: tuple[str, int], seconds: float, rate: float | None = None,
             stop_when_done: bool = False) -> None:
        t0 = time.monotonic()
        first = self.next
        end = t0 + seconds
        while time.monotonic() < end:
            now = time.monotonic()
            allowed = N if rate is None else first + int((now - t0) * rate)
            # Like the firmware ring: in-flight seqs span at most WINDOW consecutive numbers.
            low = min(self.unacked, default=self.next)
            while self.next - low < WINDOW and self.next < min(N, allowed):
                self.unacked[self.next] = 0.0
                self.next += 1
            for seq, t in list(self.unacked.items()):
                if now - t > 0.3:
                    try:
                        self.sock.sendto(packet(seq), addr)
                    except OSError:
                        pass
                    self.unacked[seq] = now
            select.select([self.sock], [], [], 0.02)
            while True:
                try:
                    data = self.sock.recv(256)
                except (BlockingIOError, ConnectionRefusedError):
                    break
                a = p.decode_ack(data, KEY)  # raises on a forged or garbled ack
                assert a.status in (p.ACK_STORED, p.ACK_DUPLICATE)
                self.dup_acks += a.status == p.ACK_DUPLICATE
                self.unacked.pop(a.seq, None)
                self.acked.add(a.seq)
            if stop_when_done and self.next >= N and not self.unacked:
                return

    def burst(self, addr: tuple[str, int], k: int) -> None:
        """Send k new records at once and read no ack: the kill that follows lands with them
        in flight (received, being stored or acknowledged, or still in the socket)."""
        now = time.monotonic()
        for _ in range(k):
            if self.next >= N or self.next - min(self.unacked, default=self.next) >= WINDOW:
                break
            self.unacked[self.next] = now
            try:
                self.sock.sendto(packet(self.next), addr)
            except OSError:
                pass
            self.next += 1


def test_sigkill_restart_20_times(tmp_path: Path) -> None:
    db, keys = tmp_path / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY})
    rng = random.Random(20261121)
    s = Sender()
    in_flight_at_kill = []
    for _ in range(20):
        proc, addr = start_gateway(db, keys)
        s.pump(addr, rng.uniform(0.05, 0.6), rate=RATE)
        # Kill mid-stream by construction, not by timing luck on a loaded machine: a burst of
        # new records is on its way when SIGKILL lands.
        s.burst(addr, rng.randint(1, 40))
        assert s.next < N and s.unacked  # the stream was not finished; records in flight
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        in_flight_at_kill.append(len(s.unacked))
        # Every sample acknowledged so far must be in the file the killed process left.
        with sqlite3.connect(db) as c:
            stored = {r[0] for r in c.execute("SELECT seq FROM samples")}
        assert s.acked <= stored, f"acked but lost: {sorted(s.acked - stored)[:10]}"
    # Every kill landed with records in flight (by construction above).
    assert all(n > 0 for n in in_flight_at_kill), in_flight_at_kill
    assert 0 < len(s.acked) < N
    proc, addr = start_gateway(db, keys)
    try:
        s.pump(addr, 120, stop_when_done=True)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    assert s.acked == set(range(N))
    with sqlite3.connect(db) as c:
        assert c.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        rows = c.execute("SELECT seq, t_in, rh_in, i_glob, rain FROM samples").fetchall()
        assert c.execute("SELECT boot, max_seq FROM devices WHERE device_id=7").fetchone() == (
            4, N - 1)
    assert len(rows) == N and len({r[0] for r in rows}) == N  # no duplicates
    for seq, t_in, rh_in, i_glob, rain in rows:
        v = values(seq)
        assert (t_in, rh_in, i_glob, rain) == (round(v[0], 2), v[1], v[4], v[6])

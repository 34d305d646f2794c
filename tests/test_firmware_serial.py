"""A board on the gateway's USB port: the real firmware under MicroPython with a fake UART wired
to a host pty, COBS frames through a 'cable' that corrupts bytes both ways, the real gateway
reading the other pty through pyserial. Every record arrives exactly once."""

from __future__ import annotations

import json
import os
import random
import select
import signal
import subprocess
import sys
import threading
import tty
from pathlib import Path

import pytest

from gateway.store.keys import write_keys
from tests.gateway_harness import wait_for
from tests.mcu_fakes.hostenv import fast_clock, micropython, run_mpy
from tests.test_firmware_e2e import (
    KEY,
    ROOT,
    Firmware,
    check_exactly_once,
    make_trace,
    run_until_delivered,
    stored,
)
from tests.test_firmware_health import stored_health

pytestmark = pytest.mark.skipif(micropython() is None, reason="micropython not installed")


class NoisyCable:
    """Relays bytes between two pty masters, flipping a fraction of bytes (seeded)."""

    def __init__(self, a: int, b: int, flip: float, seed: int) -> None:
        self.a, self.b, self.flip = a, b, flip
        self.rng = random.Random(seed)
        self.flipped = 0
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop:
            ready, _, _ = select.select([self.a, self.b], [], [], 0.1)
            for src in ready:
                try:
                    data = bytearray(os.read(src, 4096))
                except OSError:
                    continue
                for i in range(len(data)):
                    if self.rng.random() < self.flip:
                        data[i] ^= 1 << self.rng.randrange(8)
                        self.flipped += 1
                os.write(self.b if src == self.a else self.a, data)

    def close(self) -> None:
        self._stop = True
        self.thread.join(timeout=5)


def _pty() -> tuple[int, int, str]:
    m, s = os.openpty()
    tty.setraw(m)
    tty.setraw(s)
    return m, s, os.ttyname(s)


def test_firmware_over_uart_with_a_noisy_cable(tmp_path: Path) -> None:
    db, keys, trace = tmp_path / "g.db", tmp_path / "keys", tmp_path / "trace"
    write_keys(keys, {7: KEY})
    make_trace(trace)
    ma, sa, board_tty = _pty()
    mb, sb, gw_tty = _pty()
    cable = NoisyCable(ma, mb, flip=0.003, seed=11)
    log = tmp_path / "gateway.log"
    with open(log, "w") as err:
        gw = subprocess.Popen(
            [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys",
             str(keys), "--serial", gw_tty, "--maintenance-every", "0.5"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True)
    board = tmp_path / "board"
    board.mkdir()
    (board / "config.json").write_text(json.dumps({
        "device_id": 7, "key": KEY.hex(), "transport": "uart", "uart": {"id": 1},
        "sample_ms": 50, "period_s": 0.2, "ack_timeout_ms": 300, "wdt_ms": 5000 * 4, "health_s": 1,
        "pins": {"dht_in": 4, "dht_out": 16, "pyranometer": 34, "anemometer": 35, "rain": 27}}))
    os.environ["SERRA_UART_1"] = board_tty
    n = 40
    try:
        assert gw.stdout is not None
        assert select.select([gw.stdout], [], [], 60)[0], "gateway did not start"
        assert "listening serial" in gw.stdout.readline()
        fw = Firmware(board, trace, env=fast_clock(4))  # 4x; its watchdog 5 s of the host's
        try:
            recs = run_until_delivered(fw, db, 0, n, timeout=120)
            # health packets (74-byte frames) go over the UART too: one a second here
            wait_for(lambda: stored_health(db) is not None, 120, "a health packet stored")
        finally:
            fw.stop()
        check_exactly_once(recs, stored(db, 0), n)
    finally:
        os.environ.pop("SERRA_UART_1", None)
        gw.send_signal(signal.SIGTERM)
        gw.wait(timeout=30)
        cable.close()
        for fd in (ma, sa, mb, sb):
            os.close(fd)
    assert cable.flipped > 0
    # The corrupted frames were caught by COBS or by the tag, counted, never stored.
    counters = log.read_text().rsplit("counters", 1)[-1]
    assert "framing" in counters or "bad_tag" in counters or "short" in counters, counters


RECV_HEAP_MPY = r"""
import gc, machine, sys
from time import ticks_diff, ticks_ms
from uartport import UartPort
port = UartPort(machine.UART(1))
n = int(sys.argv[1])
got = 0
t0 = ticks_ms()
def pump(upto):
    global got
    while got < upto and ticks_diff(ticks_ms(), t0) < 30000:
        if port.recv() is not None:
            got += 1
pump(1)  # first call: anything allocated once is allocated now
gc.collect()
gc.disable()
before = gc.mem_alloc()
pump(n)
print("RECV", got, gc.mem_alloc() - before, port.bad_frames)
"""


def test_uart_receive_allocates_nothing_per_byte(tmp_path: Path) -> None:
    """UartPort.recv under MicroPython, the fake UART on a host pty holding 20 COBS-framed acks:
    after the first, the other 19 (684 bytes) allocate nothing on the heap (read(1) made one
    bytes object per byte received)."""
    from gateway import protocol as p
    from gateway.ingest.framing import cobs_encode

    n = 20
    frame = cobs_encode(p.encode_ack(7, 0, 1, p.ACK_STORED, 0, KEY)) + b"\0"
    m, s, name = _pty()
    try:
        os.write(m, frame * n)
        script = tmp_path / "recv_heap.py"
        script.write_text(RECV_HEAP_MPY)
        r = run_mpy(script, str(n), env={"SERRA_UART_1": name}, timeout=60)
    finally:
        os.close(m)
        os.close(s)
    assert r.returncode == 0, r.stdout + r.stderr
    _, got, heap, bad = r.stdout.split()
    assert (int(got), int(bad)) == (n, 0), r.stdout
    assert int(heap) <= 64, r.stdout  # bytes for 19 frames; read(1) took > 10,000


BACKLOG_MPY = r"""
import sys, config, main, wire
from time import ticks_diff, ticks_ms
from ring import Ring
from sensors import RainDetector
from uartport import from_config

cfg = config.parse({
    "device_id": 7, "key": "00" * 32, "transport": "uart",
    "uart": {"id": 1, "baudrate": 1200}, "sample_ms": 100, "period_s": 600,
    "ack_timeout_ms": 60000, "pins": {}})
backlog = int(sys.argv[1])
ring = Ring(cfg.ring_size)
t0 = ticks_ms()
for s in range(backlog):  # records kept through an outage, all due now, never acked here
    wire.pack_channels(ring.push(s, t0), 0, [0] * 7, [0] * 7)


class RainPin:  # the hardware edge: the rain detector's pin notes when it is read
    def __init__(self):
        self.at = []

    def value(self):
        self.at.append(ticks_ms())
        return 1


class Dog:
    def feed(self):
        pass


rain = RainPin()
main.run(cfg, 0, Dog(), None, (None, None, None, None, RainDetector(rain)), (), ring,
         from_config(cfg), max_loops=int(sys.argv[2]))
gaps = [ticks_diff(b, a) for a, b in zip(rain.at, rain.at[1:])]
print("SAMPLES", len(rain.at), "MAXGAP", max(gaps), "FIRST", ticks_diff(rain.at[0], t0))
"""


def test_a_backlog_over_a_1200_baud_uart_does_not_stall_sampling(tmp_path: Path) -> None:
    """Ten records due at once over a 1200-baud UART (65-byte frames, 0.54 s each on the line;
    the fake UART drains 120 bytes a second from the ESP32's 128-byte FIFO and its write()
    blocks as the board's does). Written as one burst of 8, they held the loop 3.3 s; sent one
    frame at a time once the last has left (txdone), sampling every 100 ms stays on time while
    the backlog drains at the line's rate."""
    m, s, name = _pty()
    try:
        script = tmp_path / "backlog.py"
        script.write_text(BACKLOG_MPY)
        # 400 passes of the loop: >= 4 s (each sleeps up to 10 ms until the next sample).
        r = run_mpy(script, "10", "400", env={"SERRA_UART_1": name}, timeout=120)
        sent = b""
        while select.select([m], [], [], 0)[0]:
            sent += os.read(m, 4096)
    finally:
        os.close(m)
        os.close(s)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout.split()
    samples, max_gap_ms = int(out[out.index("SAMPLES") + 1]), int(out[out.index("MAXGAP") + 1])
    # 100 ms apart, plus at most one 10 ms sleep and a loaded host's delay; a blocked write: 3.3 s
    assert samples >= 30 and max_gap_ms < 1500, r.stdout
    assert sent.count(b"\0") >= 6, (sent.count(b"\0"), r.stdout)  # 4 s at 0.54 s a frame


SEND_HEAP_MPY = r"""
import gc, machine, sys
from uartport import UartPort
from wire import RECORD_LEN
port = UartPort(machine.UART(1, baudrate=4000000))
rec = bytearray(range(1, RECORD_LEN + 1))
n = int(sys.argv[1])
port.send(rec)  # first call: anything allocated once is allocated now
gc.collect()
gc.disable()
before = gc.mem_alloc()
for _ in range(n):
    port.send(rec)
print("SEND", gc.mem_alloc() - before)
"""


def test_uart_send_allocates_nothing_per_frame(tmp_path: Path) -> None:
    """UartPort.send under MicroPython: 50 record frames reach the pty whole and allocate
    nothing on the heap (a memoryview slice per frame took 64 bytes each on this port)."""
    from gateway.ingest.framing import cobs_encode

    n = 50
    m, s, name = _pty()
    got = bytearray()
    try:
        script = tmp_path / "send_heap.py"
        script.write_text(SEND_HEAP_MPY)
        r = run_mpy(script, str(n), env={"SERRA_UART_1": name}, timeout=60)
        while select.select([m], [], [], 0)[0]:
            got += os.read(m, 65536)
    finally:
        os.close(m)
        os.close(s)
    assert r.returncode == 0, r.stdout + r.stderr
    assert got == (cobs_encode(bytes(range(1, 64))) + b"\0") * (n + 1)
    assert int(r.stdout.split()[-1]) <= 64, r.stdout  # bytes for 50 frames

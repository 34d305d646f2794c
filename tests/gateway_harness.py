"""Shared plumbing for the live-gateway tests: a config on a scaled clock, the gateway as a real
subprocess (ready line parsed, SIGTERM/SIGKILL), a firmware-like Python kit that tracks its acks,
and waiting on conditions with generous deadlines (never sleeping to synchronise)."""

from __future__ import annotations

import math
import os
import queue
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gateway import protocol as p
from gateway.store.keys import write_keys

ROOT = Path(__file__).resolve().parents[1]
KEY = bytes(range(1, 33))
EPOCH = 1_257_055_200.0  # 2009-11-01T06:00:00Z: the simulated weather's morning


def wait_for(cond: Callable[[], object], timeout: float, what: str, every: float = 0.05):
    """Poll ``cond`` until it is truthy (returned) or ``timeout`` [s] passes (AssertionError)."""
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(every)


def write_config(folder: Path, *, anchor: float, scale: float = 300.0, farm: str = "f1",
                 devices: tuple[int, ...] = (7,), zenoh_listen: str | None = "tcp/127.0.0.1:0",
                 zenoh_connect: str | None = None, extra: str = "", status_every_s: float = 600,
                 greenhouses: str | None = None, diagnosis: str = "enabled = false") -> Path:
    """The gateway's TOML in ``folder`` (keys beside it); ``diagnosis``: the body of its
    ``[diagnosis]`` table (off unless a test says otherwise); ``zenoh_listen`` None: none."""
    write_keys(folder / "keys.txt", {d: KEY for d in devices})
    connect = f'connect = ["{zenoh_connect}"]' if zenoh_connect else ""
    gh = greenhouses or (f'[[greenhouse]]\nname = "north"\ngreenhouse = "biskra-prototype"\n'
                         f'model = "prototype"\ninside = {devices[0]}\n')
    path = folder / "gateway.toml"
    path.write_text(f"""
[gateway]
farm = "{farm}"
db = "gw.db"
keys = "keys.txt"
status_every_s = {status_every_s}
[ingest]
listen = "127.0.0.1:0"
maintenance_s = 1
[zenoh]
listen = [{f'"{zenoh_listen}"' if zenoh_listen else ""}]
{connect}
resend_on_start_s = 2.0
[diagnosis]
{diagnosis}
[clock]
scale = {scale}
epoch = {EPOCH}
anchor = {anchor}
{extra}
{gh}
""")
    return path


class GatewayProcess:
    """``python -m gateway run`` in a subprocess; ``udp``/``zenoh`` from its ready line."""

    def __init__(self, config: Path) -> None:
        self.config = config
        self.argv = [sys.executable, "-m", "gateway", "run", "--config", str(config)]
        self.proc: subprocess.Popen | None = None
        self.udp: tuple[str, int] = ("", 0)
        self.zenoh = ""
        self.starts = 0

    def start(self, timeout: float = 90.0) -> None:
        log = open(self.config.parent / "gateway.log", "a")  # noqa: SIM115 - kept by the child
        # its temporary folders in the test's folder: a gateway the test kills leaves its
        # work folder behind (systemd's PrivateTmp clears it on a farm)
        env = {**os.environ, "TMPDIR": str(self.config.parent)}
        self.proc = subprocess.Popen(self.argv, cwd=self.config.parent, stdout=subprocess.PIPE,
                                     stderr=log, text=True, env=env)
        self.starts += 1
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, args=(self.proc, lines), daemon=True).start()
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = lines.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                self.kill()
                raise AssertionError(f"gateway not ready in {timeout} s:\n{self.log_tail()}") from None
            if not line:
                raise AssertionError(f"gateway exited at start:\n{self.log_tail()}")
            if line.startswith("serra-gateway ready"):
                break
        parts = line.split()
        host, port = parts[parts.index("udp") + 1].rsplit(":", 1)
        self.udp = (host, int(port))
        self.zenoh = parts[parts.index("zenoh") + 1] if "zenoh" in parts else ""

    @staticmethod
    def _read(proc: subprocess.Popen, lines: queue.Queue) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)
        lines.put("")  # end of output

    def log_tail(self, n: int = 30) -> str:
        path = self.config.parent / "gateway.log"
        return "\n".join(path.read_text().splitlines()[-n:]) if path.exists() else ""

    def stop(self, timeout: float = 60.0) -> int:
        if self.proc is None:
            return 0
        self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"gateway did not stop on SIGTERM:\n{self.log_tail()}") from None
        self.proc = None
        return code

    def kill(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(timeout=30)
            self.proc = None


class PyKit:
    """A firmware-like sender on the scaled clock: record k is the simulated minute k (values from
    ``trace``), sent once its minute has passed, resent until acknowledged, at most ``window``
    unacknowledged (the firmware ring); ``acked`` holds the seqs whose STORED/DUPLICATE ack came."""

    def __init__(self, device: int, trace: dict[str, np.ndarray], now: Callable[[], float],
                 boot: int = 0, window: int = 128, resend_s: float = 0.3) -> None:
        self.device, self.trace, self.now, self.boot = device, trace, now, boot
        self.window, self.resend_s = window, resend_s
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.next = 0
        self.unacked: dict[int, float] = {}
        self.acked: set[int] = set()
        self.n = len(trace["t_in"])

    def t(self, seq: int) -> float:
        """Simulated end of record ``seq``'s minute, mid-minute so jitter never crosses one."""
        return EPOCH + 60 * seq + 30

    def packet(self, seq: int) -> bytes:
        vals, st = [], []
        for i, c in enumerate(p.CHANNELS):
            v = float(self.trace[c][seq % self.n])
            ok = math.isfinite(v)
            lo, hi = p.RANGES[i]
            vals.append(min(max(v, lo), hi) if ok else None)
            st.append(p.ST_OK if ok else p.ST_TIMEOUT)
        age = max(0, int((self.now() - self.t(seq)) * 1000))
        rec = p.Record(self.device, self.boot, seq, seq * 60_000, min(age, 2**32 - 1), 60.0,
                       tuple(vals), tuple(st))
        return p.encode_record(rec, KEY)

    def send_due(self, addr: tuple[str, int] | None) -> int:
        """Send the records that are due (new ones, and resends after ``resend_s``); no ack is
        read. Returns how many were sent."""
        now_wall = time.monotonic()
        low = min(self.unacked, default=self.next)
        while self.next - low < self.window and self.t(self.next) <= self.now():
            self.unacked[self.next] = 0.0
            self.next += 1
        sent = 0
        if addr is not None:
            for seq, when in list(self.unacked.items()):
                if now_wall - when > self.resend_s:
                    try:
                        self.sock.sendto(self.packet(seq), addr)
                        sent += 1
                    except OSError:
                        pass
                    self.unacked[seq] = now_wall
        return sent

    def pump(self, addr: tuple[str, int] | None) -> None:
        """Send what is due, read acks; one round (call it in a loop)."""
        self.send_due(addr)
        select.select([self.sock], [], [], 0.02)
        self.read_acks()

    def read_acks(self) -> None:
        while True:
            try:
                data = self.sock.recv(256)
            except (BlockingIOError, ConnectionRefusedError):
                break
            a = p.decode_ack(data, KEY)
            assert a.status in (p.ACK_STORED, p.ACK_DUPLICATE), a
            self.unacked.pop(a.seq, None)
            self.acked.add(a.seq)

    def close(self) -> None:
        self.sock.close()


def sim_trace(days: float = 1.0, start: str = "2009-11-01") -> dict[str, np.ndarray]:
    """Kit columns of the reference simulator (prototype box, Bleiswijk weather), from 06:00."""
    from training.simulate import simulate

    sim = simulate(plant="prototype", weather="bleiswijk", start=start, days=days, seed=0, step=60)
    skip = 6 * 60  # the trace starts at EPOCH (06:00)
    return {c: np.asarray(sim.columns[c][skip:], dtype=float) for c in p.CHANNELS}


def store_trace(store, trace: dict[str, np.ndarray], minutes: range, device: int = 7,
                change_after: int | None = None, boot: int = 0, start: float = EPOCH) -> None:
    """Records of ``trace`` (``sim_trace``'s columns), one per minute from ``start``, stamped
    mid-minute, written to the gateway store ``store`` and aggregated into minutes; with
    ``change_after``, t_out and i_glob are +5 after that minute (another future, same past)."""
    from gateway.store.aggregate import aggregate

    items = []
    for k in minutes:
        vals, st = [], []
        for c in p.CHANNELS:
            v = float(trace[c][k])
            if change_after is not None and k > change_after and c in ("t_out", "i_glob"):
                v = v + 5.0
            ok = math.isfinite(v)
            vals.append(v if ok else None)
            st.append(p.ST_OK if ok else p.ST_TIMEOUT)
        items.append((p.Record(device, boot, k, k * 60_000, 0, 60.0, tuple(vals), tuple(st)),
                      start + 60 * k + 30))
    store.write_batch(items)
    while aggregate(store.conn):
        pass


def shifted_kit(db: Path) -> float:
    """42 h of the simulated kit (from 06:00, the least diagnose takes) whose clock is 12 h off,
    stored as kit 7's records in the gateway store ``db`` and aggregated; returns the end time.
    Its daylight falls in the site's night: diagnose warns ``site_time_mismatch``."""
    from gateway.store import Store

    trace = sim_trace(days=2.0)
    shift = 12 * 3600.0
    store = Store(db)
    try:
        store_trace(store, trace, range(len(trace["t_in"])), start=EPOCH + shift)
    finally:
        store.close()
    return EPOCH + shift + 60 * len(trace["t_in"])

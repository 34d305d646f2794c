"""The real firmware under the real MicroPython interpreter, fake hardware only (machine, dht,
network), replaying a sensor trace from the shipped Bleiswijk weather, sending real UDP through a
proxy that drops 30 % of datagrams in both directions to the real gateway on 127.0.0.1."""

from __future__ import annotations

import csv
import gzip
import hashlib
import json
import math
import random
import select
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

from gateway import protocol as p
from gateway.store.keys import write_keys
from tests.mcu_fakes.hostenv import MCU, fast_clock, micropython, mpy_env

T = TypeVar("T")

ROOT = Path(__file__).resolve().parents[1]
KEY = hashlib.sha256(b"serra test key: device 7").digest()
WEATHER = ROOT / "training" / "data" / "bleiswijk" / "bleiswijk_weather_5min.csv.gz"
pytestmark = pytest.mark.skipif(micropython() is None, reason="micropython not installed")


def make_trace(path: Path, n: int = 400) -> None:
    """Bleiswijk outdoor weather as raw sensor readings, with the failures real DHT22s show."""
    rows = []
    if WEATHER.exists():
        with gzip.open(WEATHER, "rt") as f:
            r = csv.reader(f)
            head = next(r)
            next(r), next(r)
            idx = {k: head.index(k) for k in ("tOut", "vpOut", "wind", "iGlob")}
            for i, row in enumerate(r):
                if i >= n:
                    break
                rows.append({k: float(row[j]) for k, j in idx.items()})
    while len(rows) < n:  # fallback: a synthetic day
        h = len(rows) / 12
        rows.append({"tOut": 10 + 5 * math.sin(h / 4), "vpOut": 900.0, "wind": 3.0,
                     "iGlob": max(0.0, 600 * math.sin(h / 4))})
    faults = ["timeout", "checksum", "zero"]
    dht_in, dht_out, pyr, anem, rain = [], [], [], [], []
    for i, w in enumerate(rows):
        es = 610.78 * math.exp(17.27 * w["tOut"] / (w["tOut"] + 237.3))
        rh = max(0.0, min(100.0, 100 * w["vpOut"] / es))
        dht_out.append(faults[i % 3] if i % 7 == 3 else [round(w["tOut"], 1), round(rh, 1)])
        dht_in.append(faults[i % 3] if i % 11 == 5 else [round(w["tOut"] + 8, 1), 70.0])
        pyr.append(int(120 + w["iGlob"] / 0.0305))
        anem.append(int(w["wind"] / 20.0 * 65535 / 3.1))
        rain.append(0 if i % 40 < 5 else 1)  # active low: wet for 5 readings in 40
    pyr[17] = 65535  # one saturated ADC reading
    path.mkdir(exist_ok=True)
    for name, seq in (("dht_4", dht_in), ("dht_16", dht_out), ("adc_34", pyr), ("adc_35", anem),
                      ("pin_27", rain)):
        lines = [x if isinstance(x, str) else " ".join(map(str, x)) if isinstance(x, list)
                 else str(x) for x in seq]
        (path / f"{name}.txt").write_text("\n".join(lines) + "\n")


class LossyProxy:
    """UDP relay firmware <-> gateway dropping a fraction of datagrams each way (seeded)."""

    def __init__(self, gateway: tuple[str, int], loss: float, seed: int) -> None:
        self.gw = gateway
        self.loss = loss
        self.rng = random.Random(seed)
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.port = self.front.getsockname()[1]
        self.client: tuple[str, int] | None = None
        self.stats = {"up": 0, "up_dropped": 0, "down": 0, "down_dropped": 0}
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.1)
            for s in ready:
                data, addr = s.recvfrom(4096)
                up = s is self.front
                if up:
                    self.client = addr
                key = "up" if up else "down"
                self.stats[key] += 1
                if self.rng.random() < self.loss:
                    self.stats[key + "_dropped"] += 1
                    continue
                if up:
                    self.back.sendto(data, self.gw)
                elif self.client:
                    self.front.sendto(data, self.client)

    def close(self) -> None:
        self._stop = True
        self.thread.join(timeout=5)
        self.front.close()
        self.back.close()


def start_gateway(db: Path, keys: Path, log: Path | None = None
                  ) -> tuple[subprocess.Popen, tuple[str, int]]:
    with open(log or "/dev/null", "a") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys", str(keys),
             "--listen", "127.0.0.1:0", "--maintenance-every", "0.5"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 60)
    assert ready, "gateway did not start"
    line = proc.stdout.readline()
    host, port = line.split()[-1].rsplit(":", 1)
    return proc, (host, int(port))


class Firmware:
    def __init__(self, workdir: Path, trace: Path, wifi: str = "ok", outage: str = "",
                 env: dict[str, str] | None = None) -> None:
        """env: more environment for the interpreter (e.g. MICROPYPATH with another fake)."""
        exe = micropython()
        assert exe
        self.lines: list[str] = []
        self.changed = threading.Condition()  # notified at every console line and at the end
        self.ended = False
        self.proc = subprocess.Popen(
            [exe, "-X", "heapsize=96K", str(MCU / "main.py")], cwd=workdir,
            env=mpy_env({"SERRA_TRACE": str(trace), "SERRA_WIFI": wifi,
                         "SERRA_WIFI_OUTAGE": outage, **(env or {})}),
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self.changed:
                self.lines.append(line.rstrip("\n"))
                self.changed.notify_all()
        with self.changed:
            self.ended = True
            self.changed.notify_all()

    def wait(self, cond: Callable[[], T], timeout: float, what: str) -> T:
        """``cond()``'s first truthy value, checked again at each console line (no polling);
        fails naming ``what`` when the firmware ends first or ``timeout`` [s] passes."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while not (value := cond()):
                if self.ended:
                    raise AssertionError("firmware exited:\n" + "\n".join(self.lines[-30:]))
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"not {what} in {timeout} s:\n"
                                         + "\n".join(self.lines[-20:]))
                self.changed.wait(left)
        return value

    def records(self) -> dict[int, list[tuple[int, int]]]:
        out = {}
        for line in list(self.lines):
            if line.startswith("REC "):
                parts = line.split()
                out[int(parts[1])] = [tuple(map(int, x.split(":"))) for x in parts[2:]]
        return out

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.thread.join(timeout=5)


def stored(db: Path, boot: int) -> dict[int, tuple]:
    with sqlite3.connect(db) as c:
        cols = ", ".join(f"{ch}, {ch}_st" for ch in p.CHANNELS)
        return {r[0]: r[1:] for r in c.execute(
            f"SELECT seq, {cols} FROM samples WHERE device_id=7 AND boot=?", (boot,))}


def run_until_delivered(fw: Firmware, db: Path, boot: int, n: int, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if fw.proc.poll() is not None:
            raise AssertionError("firmware exited:\n" + "\n".join(fw.lines[-30:]))
        recs = fw.records()
        if len(recs) >= n and all(s in stored(db, boot) for s in range(n)):
            return recs
        time.sleep(0.2)
    raise AssertionError(f"not delivered in {timeout} s; firmware said:\n"
                         + "\n".join(fw.lines[-20:]))


def check_exactly_once(recs: dict, rows: dict, n: int) -> None:
    for seq in range(n):
        row = rows[seq]
        for i, (raw, st) in enumerate(recs[seq]):
            assert row[2 * i + 1] == st, (seq, p.CHANNELS[i])
            if st >= 0x10:
                assert raw == p.MISSING and row[2 * i] is None
            else:
                assert row[2 * i] == pytest.approx(raw * p.SCALES[i]), (seq, p.CHANNELS[i])


def wait_for_line(path: Path, text: str, fw: Firmware, timeout: float) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for line in path.read_text().splitlines():
            if text in line:
                return line
        if fw.proc.poll() is not None:
            raise AssertionError("firmware exited:\n" + "\n".join(fw.lines[-30:]))
        time.sleep(0.2)
    raise AssertionError(f"no {text!r} in {path} within {timeout} s:\n{path.read_text()}")


def reflash(dev: Path, keys: Path) -> None:
    """What a farm does for a reflashed board: the flash lost its boot counter, the gateway
    refuses boot 0 naming the command, `keys rotate` makes a new key for config.json."""
    for f in dev.glob("boot.cnt*"):
        f.unlink()
    r = subprocess.run([sys.executable, "-m", "gateway", "keys", "rotate", "7", "--keys",
                        str(keys)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    cfg = json.loads((dev / "config.json").read_text())
    cfg.update(json.loads("{" + r.stdout.strip().rstrip(",") + "}"))
    (dev / "config.json").write_text(json.dumps(cfg))


E2E_RATE = 4
"""The board's clock rate (``fast_clock``) in the lossy-UDP test, whose watchdog is 5000 board ms
times it: 5 s of the host's, as before the fast clock. At 5000 board ms a 1.25 s stall of the
interpreter on a loaded machine reset the board mid-test ("firmware exited"); the loop never
blocks (it feeds the watchdog every pass, <= 10 board ms apart) and the longest Wi-Fi backoff
there is 2 board s, so 5000 caught nothing the longer one does not."""


def test_firmware_delivers_every_record_exactly_once_over_lossy_udp(tmp_path: Path) -> None:
    db, keys, trace = tmp_path / "g.db", tmp_path / "keys", tmp_path / "trace"
    gw_log = tmp_path / "gateway.log"
    write_keys(keys, {7: KEY})
    make_trace(trace)
    gw, addr = start_gateway(db, keys, gw_log)
    proxy = LossyProxy(addr, loss=0.30, seed=5)
    dev = tmp_path / "board"
    dev.mkdir()
    (dev / "config.json").write_text(json.dumps({
        "device_id": 7, "key": KEY.hex(), "wifi": {"ssid": "serra", "password": "pw"},
        "gateway": {"host": "127.0.0.1", "port": proxy.port}, "sample_ms": 25, "period_s": 0.1,
        "ack_timeout_ms": 100, "wdt_ms": 5000 * E2E_RATE,
        "pins": {"dht_in": 4, "dht_out": 16, "pyranometer": 34, "anemometer": 35, "rain": 27}}))
    n, clock = 120, fast_clock(E2E_RATE)
    try:
        # First boot: Wi-Fi fails twice before connecting (backoff, no reboot).
        fw = Firmware(dev, trace, wifi="fail,fail,ok", env=clock)
        try:
            recs = run_until_delivered(fw, db, 0, n, timeout=120)
        finally:
            fw.stop()
        assert any("wifi backoff" in x for x in fw.lines)
        assert sum("connect attempt" in x for x in fw.lines) >= 3
        check_exactly_once(recs, stored(db, 0), n)
        # Second boot: the flash counter moves on, sequence numbers restart at 0, still unique.
        # The access point vanishes for 2 s mid-stream: records wait in the ring, no reset.
        fw2 = Firmware(dev, trace, outage="1000:2000", env=clock)
        try:
            recs2 = run_until_delivered(fw2, db, 1, 40, timeout=90)
        finally:
            fw2.stop()
        assert "serra: device 7 boot 1" in fw2.lines
        check_exactly_once(recs2, stored(db, 1), 40)
        states = [x for x in fw2.lines if x.startswith("serra: wifi")]
        assert states.count("serra: wifi up") >= 2 and "serra: wifi backoff" in states, states
        assert not any("FAKE WDT" in x or "machine.reset" in x for x in fw.lines + fw2.lines)
        # Reflashed: the flash lost its boot counter, the board starts again at boot 0. The
        # gateway refuses it (a replay looks the same), naming the device and the command.
        first = stored(db, 0)
        for f in dev.glob("boot.cnt*"):
            f.unlink()
        fw3 = Firmware(dev, trace, env=clock)
        try:
            line = wait_for_line(gw_log, "device 7 refused", fw3, timeout=60)
        finally:
            fw3.stop()
        assert "serra: device 7 boot 0" in fw3.lines
        assert f"python -m gateway keys rotate 7 --keys {keys}" in line, line
        # The recovery: a new key, the gateway restarted, the board back at boot 0.
        reflash(dev, keys)
        gw.send_signal(signal.SIGTERM)
        gw.wait(timeout=30)
        gw, proxy.gw = start_gateway(db, keys, gw_log)
        fw4 = Firmware(dev, trace, env=clock)
        try:
            recs4 = run_until_delivered(fw4, db, 2, 20, timeout=90)  # stored after boot 1
        finally:
            fw4.stop()
        assert "serra: device 7 boot 0" in fw4.lines
        check_exactly_once(recs4, stored(db, 2), 20)
        assert stored(db, 0) == first  # nothing of the first key's data lost or overwritten
    finally:
        proxy.close()
        gw.send_signal(signal.SIGTERM)
        gw.wait(timeout=30)
    # The link was lossy both ways, and nothing was stored twice.
    st = proxy.stats
    assert 0.15 < st["up_dropped"] / st["up"] < 0.45
    assert 0.15 < st["down_dropped"] / st["down"] < 0.45
    with sqlite3.connect(db) as c:
        dup = c.execute("SELECT count(*) - count(DISTINCT device_id || '/' || boot || '/' || seq)"
                        " FROM samples").fetchone()[0]
        assert dup == 0
        assert c.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    # Failed DHT22 reads travelled as missing with their code, never as a made-up value.
    codes = {st for r in recs.values() for _, st in r}
    assert {p.ST_OK, p.ST_PARTIAL} <= codes
    assert codes & {p.ST_TIMEOUT, p.ST_CHECKSUM}

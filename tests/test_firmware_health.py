"""Health packets from the real firmware under the real MicroPython interpreter (fake hardware
only) to the real gateway: after an outage longer than the ring, the board's own drop count
reaches the store within seconds, equal to its console, long before the seq span lets the
gateway infer it; the same packet replayed, or tampered with, is refused by reason."""

from __future__ import annotations

import json
import signal
import socket
import sqlite3
from pathlib import Path

import pytest

from gateway import protocol as p
from gateway.store.keys import write_keys
from gateway.store.losses import RING_MAX_SPAN
from tests.mcu_fakes.hostenv import FAST, fast_clock, micropython
from tests.test_firmware_e2e import KEY, Firmware, LossyProxy, make_trace, start_gateway, wait_for_line
from tests.test_firmware_outage import RING, losses, mem_lines

pytestmark = pytest.mark.skipif(micropython() is None, reason="micropython not installed")
_COLS = ("hseq", "records", "dropped_full", "dropped_old", "sent", "acked", "rejected",
         "send_errors", "heap_free", "ring", "rssi_dbm", "uptime_s", "boot")


def health_lines(fw: Firmware) -> dict[int, dict[str, int]]:
    """hseq → the firmware's console line `HEALTH <hseq> records <n> dropped <n> full <n> ...`."""
    out = {}
    for line in list(fw.lines):
        if line.startswith("HEALTH "):
            f = line.split()
            out[int(f[1])] = {f[i]: int(f[i + 1]) for i in range(2, len(f), 2)}
    return out


def stored_health(db: Path) -> dict[str, int] | None:
    with sqlite3.connect(db) as c:
        r = c.execute(f"SELECT {', '.join(_COLS)} FROM board_health WHERE device_id = 7"
                      ).fetchone()
    return dict(zip(_COLS, r, strict=True)) if r else None


def test_the_boards_drop_count_arrives_in_a_health_packet(tmp_path: Path) -> None:
    db, keys, trace, log = tmp_path / "g.db", tmp_path / "keys", tmp_path / "trace", \
        tmp_path / "gateway.log"
    write_keys(keys, {7: KEY})
    make_trace(trace)
    gw, addr = start_gateway(db, keys, log)
    proxy = LossyProxy(addr, loss=1.0, seed=6)  # the gateway is away
    dev = tmp_path / "board"
    dev.mkdir()
    (dev / "config.json").write_text(json.dumps({
        "device_id": 7, "key": KEY.hex(), "wifi": {"ssid": "serra", "password": "pw"},
        "gateway": {"host": "127.0.0.1", "port": proxy.port}, "sample_ms": 25,
        "period_s": 0.1, "ack_timeout_ms": 100, "wdt_ms": 5000 * FAST, "ring_size": RING,
        "health_s": 1, "pins": {"dht_in": 4, "dht_out": 16}}))
    fw = Firmware(dev, trace, env=fast_clock())  # see board() in test_firmware_outage
    cli = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        fw.wait(lambda: len(mem_lines(fw)) >= 4, 180, "200 records")
        proxy.loss = 0.0  # back

        def arrived() -> tuple[dict[str, int], dict[str, int]] | None:
            got = stored_health(db)
            if got is None or got["dropped_full"] == 0:
                return None
            said = health_lines(fw).get(got["hseq"])
            return (got, said) if said else None

        got, said = fw.wait(arrived, 120, "a health packet with the drops stored")
        # Stored as the board said it, field by field (rssi from the fake Wi-Fi).
        named = {"full": "dropped_full", "old": "dropped_old", "errors": "send_errors",
                 "heap": "heap_free", "rssi": "rssi_dbm", "uptime": "uptime_s"}
        assert {k: got[named.get(k, k)] for k in said if k != "dropped"} == {
            k: v for k, v in said.items() if k != "dropped"}
        assert said["dropped"] == got["dropped_full"] + got["dropped_old"]
        assert said["rssi"] == -61 and got["boot"] == 0
        assert got["dropped_old"] == 0 and got["dropped_full"] >= 200 - RING
        assert got["records"] == (got["ring"] + got["acked"] + got["rejected"]
                                  + got["dropped_full"] + got["dropped_old"])
        # The seq gaps make these final only RING_MAX_SPAN records later.
        assert got["records"] < got["dropped_full"] + RING_MAX_SPAN
        assert losses(db).get(0, 0) < got["dropped_full"]
        line = wait_for_line(log, "dropped from its ring", fw, timeout=60)
        assert "device 7 boot 0 reports" in line, line
        reported = int(line.split(" reports ")[1].split()[0])
        assert 0 < reported <= said["dropped"], line  # the first report may precede this one
        # That very packet again (same fields, same bytes), and a tampered copy.
        again = p.encode_health(p.BoardHealth(
            7, 0, got["hseq"], got["rssi_dbm"], got["uptime_s"], got["records"],
            got["dropped_full"], got["dropped_old"], got["sent"], got["acked"], got["rejected"],
            got["send_errors"], got["heap_free"], got["ring"]), KEY)
        tampered = bytearray(again)
        tampered[29] ^= 0x01  # dropped_full
        cli.sendto(again, addr)
        cli.sendto(bytes(tampered), addr)
        wait_for_line(log, "rejected: health_replay device 7", fw, timeout=60)
        wait_for_line(log, "rejected: bad_tag health packet of device 7", fw, timeout=60)
        # Records kept flowing around the health packets: acked, the ring emptied.
        fw.wait(lambda: (m := mem_lines(fw)) and m[-1]["ring"] < 10 and m[-1]["acked"] > RING,
                120, "the ring drained")
    finally:
        cli.close()
        fw.stop()
        proxy.close()
        gw.send_signal(signal.SIGTERM)
        gw.wait(timeout=30)

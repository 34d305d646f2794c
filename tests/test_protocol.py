"""Wire format v1: shared vectors on both implementations, and decoder fuzzing."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway import protocol as p
from tests.mcu_fakes.hostenv import micropython, run_mpy

VECTORS = Path(__file__).parent / "vectors" / "wire_v1.json"
DOC = json.loads(VECTORS.read_text())
KEYS = {int(k): bytes.fromhex(v) for k, v in DOC["devices"].items()}


def _record_of(v: dict) -> p.Record:
    values = tuple(
        None if st >= 0x10 else raw * sc
        for raw, st, sc in zip(v["raw"], v["status"], p.SCALES, strict=True)
    )
    return p.Record(v["device_id"], v["boot"], v["seq"], v["tick_ms"], v["age_ms"],
                    v["period_ds"] / 10, values, tuple(v["status"]))


@pytest.mark.parametrize("v", DOC["records"], ids=lambda v: v["name"])
def test_record_vectors_cpython(v: dict) -> None:
    pkt = bytes.fromhex(v["packet"])
    assert len(pkt) == p.RECORD_LEN or not v["encodable"]
    if v["expect"] == "ok":
        rec = p.decode_record(pkt, KEYS)
        assert (rec.device_id, rec.boot, rec.seq, rec.tick_ms, rec.age_ms) == (
            v["device_id"], v["boot"], v["seq"], v["tick_ms"], v["age_ms"])
        assert list(rec.status) == v["status"]
        for got, raw, stc, sc in zip(rec.values, v["raw"], v["status"], p.SCALES, strict=True):
            assert (got is None) == (stc >= 0x10)
            if got is not None:
                assert got == pytest.approx(raw * sc)
        assert p.encode_record(rec, bytes.fromhex(v["key"])) == pkt
    else:
        with pytest.raises(p.ProtocolError) as e:
            p.decode_record(pkt, KEYS)
        assert e.value.reason == v["expect"]
    if v["encodable"] and v["expect"] in ("ok", "malformed"):
        # The encoder is a faithful inverse for well-formed values.
        if v["expect"] == "ok":
            assert p.encode_record(_record_of(v), bytes.fromhex(v["key"])) == pkt


@pytest.mark.parametrize("v", DOC["acks"], ids=lambda v: v["name"])
def test_ack_vectors_cpython(v: dict) -> None:
    pkt = bytes.fromhex(v["packet"])
    key = bytes.fromhex(v["key"])
    if v["valid"]:
        a = p.decode_ack(pkt, key)
        assert (a.device_id, a.boot, a.seq, a.status, a.reason) == (
            v["device_id"], v["boot"], v["seq"], v["status"], v["reason"])
        assert p.encode_ack(a.device_id, a.boot, a.seq, a.status, a.reason, key) == pkt
    else:
        with pytest.raises(p.ProtocolError):
            p.decode_ack(pkt, key)


MPY_VECTORS = r"""
import sys, json, binascii
import wire
doc = json.load(open(sys.argv[1]))
fails = 0
n = 0
buf = bytearray(wire.RECORD_LEN)
for v in doc["records"]:
    if not v["encodable"]:
        continue
    mac = wire.Hmac(binascii.unhexlify(v["key"]))
    wire.pack_record(buf, v["device_id"], v["boot"], v["seq"], v["tick_ms"], v["period_ds"],
                     v["raw"], v["status"])
    wire.seal(buf, v["age_ms"], mac)
    n += 1
    if binascii.hexlify(buf).decode() != v["packet"]:
        print("RECORD MISMATCH", v["name"]); fails += 1
for v in doc["acks"]:
    mac = wire.Hmac(binascii.unhexlify(v["key"]))
    got = wire.parse_ack(binascii.unhexlify(v["packet"]), v["device_id"], mac)
    n += 1
    want = (v["boot"], v["seq"], v["status"], v["reason"]) if v["valid"] else None
    if got != want:
        print("ACK MISMATCH", v["name"], got, want); fails += 1
print("checked", n, "failed", fails)
"""


@pytest.mark.skipif(micropython() is None, reason="micropython interpreter not installed")
def test_vectors_micropython(tmp_path: Path) -> None:
    script = tmp_path / "vectors_mpy.py"
    script.write_text(MPY_VECTORS)
    r = run_mpy(script, str(VECTORS), timeout=60)
    assert r.returncode == 0, r.stderr
    n_enc = sum(v["encodable"] for v in DOC["records"]) + len(DOC["acks"])
    assert f"checked {n_enc} failed 0" in r.stdout, r.stdout + r.stderr


GOOD = bytes.fromhex(DOC["records"][0]["packet"])


def _classify(data: bytes) -> str:
    try:
        p.decode_record(data, KEYS)
    except p.ProtocolError as e:
        assert e.reason in p.REASONS
        return e.reason
    return "ok"


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200))
def test_fuzz_random_bytes_never_crash_never_accept(data: bytes) -> None:
    assert _classify(data) != "ok" or data == GOOD


@settings(max_examples=400, deadline=None)
@given(st.integers(0, p.RECORD_LEN - 1), st.integers(1, 255))
def test_fuzz_single_byte_flips_rejected(pos: int, flip: int) -> None:
    data = bytearray(GOOD)
    data[pos] ^= flip
    assert _classify(bytes(data)) != "ok"


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=p.RECORD_BODY_LEN, max_size=p.RECORD_BODY_LEN))
def test_fuzz_valid_tag_arbitrary_body_is_checked_not_crashed(body: bytes) -> None:
    # An authenticated but arbitrary body (a buggy firmware): semantic checks still apply.
    body = p.MAGIC + bytes([1, 1]) + struct.pack(">I", 7) + body[8:]
    pkt = body + p.tag(KEYS[7], body)
    r = _classify(pkt)
    assert r in ("ok", "malformed", "out_of_range")
    if r == "ok":
        rec = p.decode_record(pkt, KEYS)
        for v, (lo, hi) in zip(rec.values, p.RANGES, strict=True):
            assert v is None or lo <= v <= hi

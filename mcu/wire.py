"""Serra wire format v1 (same spec as gateway/protocol.py, byte table in docs/wire-format.md).

Record packet: 63 bytes; health packet (the board's counters, no ack): 72 bytes; big-endian,
HMAC-SHA256 tag truncated to 16 bytes. MicroPython has hashlib.sha256 but no hmac module, so HMAC
(RFC 2104) is built here from two hash passes.

Names starting with "_" are compile-time constants: they take no RAM on the board (no global,
no interned name). Only what other modules use is public.
"""

import hashlib
import struct

from micropython import const

_MAGIC = b"SR"
_VERSION = const(1)
_TYPE_RECORD = const(1)
_TYPE_ACK = const(2)
_TAG_LEN = const(16)
_HEAD_LEN = const(26)  # magic .. period_ds; then 7 * (int16 value + uint8 status)
CHAN_LEN = const(21)
_BODY_LEN = const(47)  # _HEAD_LEN + CHAN_LEN
RECORD_LEN = const(63)
_AGE_OFF = const(20)
_ACK_BODY_LEN = const(18)
ACK_LEN = const(34)
ACK_REJECTED = const(2)  # ack status: 0 stored, 1 duplicate, 2 rejected (final)
_TYPE_HEALTH = const(3)
_HEALTH_LAYOUT = const(1)
_HEALTH_BODY_LEN = const(56)
HEALTH_LEN = const(72)


class Hmac:
    """HMAC-SHA256 with the padded keys computed once per device key."""

    def __init__(self, key: bytes) -> None:
        if len(key) > 64:
            key = hashlib.sha256(key).digest()
        k = bytearray(64)
        k[: len(key)] = key
        self._ipad = bytes(b ^ 0x36 for b in k)
        self._opad = bytes(b ^ 0x5C for b in k)

    def digest(self, msg) -> bytes:
        h = hashlib.sha256(self._ipad)
        h.update(msg)
        inner = h.digest()
        h = hashlib.sha256(self._opad)
        h.update(inner)
        return h.digest()


def pack_channels(buf, off: int, raw, status) -> None:
    """Write the seven (int16 value, uint8 status) pairs (CHAN_LEN bytes) at buf[off:]."""
    for i in range(7):
        struct.pack_into(">hB", buf, off + 3 * i, raw[i], status[i])


def pack_head(buf, dev: int, boot: int, seq: int, tick, period_ds: int) -> None:
    """Write bytes 0..25 (header, age 0) of a record into buf (>= RECORD_LEN bytes)."""
    struct.pack_into(">2sBBIIIIIH", buf, 0, _MAGIC, _VERSION, _TYPE_RECORD, dev, boot, seq,
                     tick & 0xFFFFFFFF, 0, period_ds)


def pack_record(buf, dev: int, boot: int, seq: int, tick, period_ds: int, raw, status) -> None:
    """Write the body of a record into buf (>= RECORD_LEN bytes); age and tag come at send."""
    pack_head(buf, dev, boot, seq, tick, period_ds)
    pack_channels(buf, _HEAD_LEN, raw, status)


def seal(buf, age_ms: int, mac: Hmac) -> None:
    """Set the age field and the tag; called before each (re)transmission."""
    struct.pack_into(">I", buf, _AGE_OFF, age_ms & 0xFFFFFFFF)
    mv = memoryview(buf)
    mv[_BODY_LEN:RECORD_LEN] = mac.digest(mv[:_BODY_LEN])[:_TAG_LEN]


def seal_health(buf, mac: Hmac, dev: int, boot: int, hseq: int, rssi: int, c) -> None:
    """Write a whole health packet into buf (>= HEALTH_LEN bytes): rssi in dBm (-128 unknown),
    c the nine uint32 counters (uptime_s, records, dropped_full, dropped_old, sent, acked,
    rejected, send_errors, heap_free) then the ring's count (uint16), in that order."""
    struct.pack_into(">2sBBIIIBbIIIIIIIIIH", buf, 0, _MAGIC, _VERSION, _TYPE_HEALTH, dev, boot,
                     hseq, _HEALTH_LAYOUT, rssi, c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7],
                     c[8], c[9])
    mv = memoryview(buf)
    mv[_HEALTH_BODY_LEN:HEALTH_LEN] = mac.digest(mv[:_HEALTH_BODY_LEN])[:_TAG_LEN]


def parse_ack(data, dev: int, mac: Hmac):
    """Return (boot, seq, status, reason) of a genuine ack for this device, else None."""
    if len(data) != ACK_LEN:
        return None
    magic, ver, typ, adev, boot, seq, st, reason = struct.unpack_from(">2sBBIIIBB", data, 0)
    if magic != _MAGIC or ver != _VERSION or typ != _TYPE_ACK or adev != dev:
        return None
    good = mac.digest(memoryview(data)[:_ACK_BODY_LEN])
    # Constant-time compare: a forged ack would silently drop a record from the ring.
    diff = 0
    for i in range(_TAG_LEN):
        diff |= good[i] ^ data[_ACK_BODY_LEN + i]
    if diff:
        return None
    return boot, seq, st, reason

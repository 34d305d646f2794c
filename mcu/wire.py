"""Serra wire format v1 (same spec as gateway/protocol.py, byte table in docs/wire-format.md).

Record packet: 63 bytes, big-endian, HMAC-SHA256 tag truncated to 16 bytes. MicroPython has
hashlib.sha256 but no hmac module, so HMAC (RFC 2104) is built here from two hash passes.
"""

import hashlib
import struct

from micropython import const

MAGIC = b"SR"
VERSION = const(1)
TYPE_RECORD = const(1)
TYPE_ACK = const(2)
TAG_LEN = const(16)
N_CHAN = const(7)  # t_in, rh_in, t_out, rh_out, i_glob, wind, rain
HEAD_FMT = ">2sBBIIIIIH"
HEAD_LEN = const(26)
BODY_LEN = const(47)  # HEAD_LEN + 7 * (int16 value + uint8 status)
RECORD_LEN = const(63)
AGE_OFF = const(20)
ACK_FMT = ">2sBBIIIBB"
ACK_BODY_LEN = const(18)
ACK_LEN = const(34)
MISSING = const(-32768)

ACK_STORED = const(0)
ACK_DUPLICATE = const(1)
ACK_REJECTED = const(2)

# Raw int16 units per channel (value = raw * scale): 0.01 degC, 0.01 %, 0.1 W m-2, 0.01 m s-1.
SCALE_INV = (100, 100, 100, 100, 10, 100, 1)


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


def to_raw(value: float, chan: int) -> int:
    return int(round(value * SCALE_INV[chan]))


def pack_record(buf, dev: int, boot: int, seq: int, tick, period_ds: int, raw, status) -> None:
    """Write the body of a record into buf (>= RECORD_LEN bytes); age and tag come at send."""
    struct.pack_into(HEAD_FMT, buf, 0, MAGIC, VERSION, TYPE_RECORD, dev, boot, seq,
                     tick & 0xFFFFFFFF, 0, period_ds)
    off = HEAD_LEN
    for i in range(N_CHAN):
        struct.pack_into(">hB", buf, off, raw[i], status[i])
        off += 3


def seal(buf, age_ms: int, mac: Hmac) -> None:
    """Set the age field and the tag; called before each (re)transmission."""
    struct.pack_into(">I", buf, AGE_OFF, age_ms & 0xFFFFFFFF)
    mv = memoryview(buf)
    mv[BODY_LEN:RECORD_LEN] = mac.digest(mv[:BODY_LEN])[:TAG_LEN]


def record_seq(buf) -> int:
    return struct.unpack_from(">I", buf, 12)[0]


def parse_ack(data, dev: int, mac: Hmac):
    """Return (boot, seq, status, reason) of a genuine ack for this device, else None."""
    if len(data) != ACK_LEN:
        return None
    magic, ver, typ, adev, boot, seq, st, reason = struct.unpack_from(ACK_FMT, data, 0)
    if magic != MAGIC or ver != VERSION or typ != TYPE_ACK or adev != dev:
        return None
    mv = memoryview(data)
    good = mac.digest(mv[:ACK_BODY_LEN])
    # Constant-time compare: a forged ack would silently drop a record from the ring.
    diff = 0
    for i in range(TAG_LEN):
        diff |= good[i] ^ data[ACK_BODY_LEN + i]
    if diff:
        return None
    return boot, seq, st, reason

"""Serra wire format v1: record packets from the kit, authenticated acknowledgements, and the
board's health packets (its own counters; no ack).

One spec with mcu/wire.py (MicroPython); both pass the vectors in tests/vectors/. The byte table
is in docs/wire-format.md. Big-endian, fixed size, HMAC-SHA256 truncated to 16 bytes.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

MAGIC = b"SR"
VERSION = 1
TYPE_RECORD = 0x01
TYPE_ACK = 0x02
TYPE_HEALTH = 0x03
TAG_LEN = 16

# magic, version, type, device_id, boot, seq, tick_ms, age_ms, period_ds
_HEAD = struct.Struct(">2sBBIIIIIH")
CHANNELS = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "rain")
UNITS = ("degC", "%", "degC", "%", "W m-2", "m s-1", "1")
# Physical value = raw int16 * scale.
SCALES = (0.01, 0.01, 0.01, 0.01, 0.1, 0.01, 1.0)
# Physical ranges accepted by the gateway (DHT22 limits, solar constant with margin, storm wind).
RANGES = (
    (-40.0, 80.0),
    (0.0, 100.0),
    (-40.0, 80.0),
    (0.0, 100.0),
    (0.0, 2000.0),
    (0.0, 75.0),
    (0.0, 1.0),
)
_CHAN = struct.Struct(">" + "hB" * len(CHANNELS))
_BODY = struct.Struct(_HEAD.format + "hB" * len(CHANNELS))
_SCALE_INV = (100, 100, 100, 100, 10, 100, 1)  # exact decimal: value = raw / inv
MISSING = -32768  # raw sentinel: the value was not measured

RECORD_BODY_LEN = _HEAD.size + _CHAN.size  # bytes covered by the tag
RECORD_LEN = RECORD_BODY_LEN + TAG_LEN  # 63

# magic, version, type, device_id, boot, seq, status, reason
_ACK = struct.Struct(">2sBBIIIBB")
ACK_LEN = _ACK.size + TAG_LEN  # 34

# magic, version, type, device_id, boot, hseq, layout, rssi_dbm, uptime_s, records,
# dropped_full, dropped_old, sent, acked, rejected, send_errors, heap_free, ring
_HEALTH = struct.Struct(">2sBBIIIBbIIIIIIIIIH")
HEALTH_BODY_LEN = _HEALTH.size  # 56
HEALTH_LEN = HEALTH_BODY_LEN + TAG_LEN  # 72
HEALTH_LAYOUT = 1
RSSI_UNKNOWN = -128

# Channel status codes. Below 0x10 the value is present, from 0x10 on it is missing and the raw
# value must be MISSING: a failed read is never sent as a made-up number.
ST_OK = 0x00
ST_PARTIAL = 0x01  # averaged over the good reads of the period; some reads failed
ST_NO_SENSOR = 0x10  # channel not fitted / disabled in the config
ST_TIMEOUT = 0x11  # sensor did not answer (DHT22 bus timeout)
ST_CHECKSUM = 0x12  # corrupted frame (bad checksum, or the all-zero DHT22 frame)
ST_RANGE = 0x13  # sensor answered outside its physical range
ST_SATURATED = 0x14  # ADC at full scale: true value unknown
ST_NOT_READY = 0x15  # no read completed yet in this period
STATUS_NAMES = {
    ST_OK: "ok",
    ST_PARTIAL: "partial",
    ST_NO_SENSOR: "no_sensor",
    ST_TIMEOUT: "timeout",
    ST_CHECKSUM: "checksum",
    ST_RANGE: "range",
    ST_SATURATED: "saturated",
    ST_NOT_READY: "not_ready",
}

# Acknowledgement status.
ACK_STORED = 0  # durable in the gateway store
ACK_DUPLICATE = 1  # already stored earlier (a resend after a lost ack)
ACK_REJECTED = 2  # authenticated but invalid: final, do not resend

# Rejection reasons (ingest counters use these names; codes travel in ACK_REJECTED acks).
REASONS = (
    "short",
    "long",
    "bad_magic",
    "bad_version",
    "bad_type",
    "unknown_device",
    "bad_tag",
    "malformed",
    "out_of_range",
    "replay_old_boot",
    "replay_old_seq",
)
REASON_CODES = {name: i + 1 for i, name in enumerate(REASONS)}


class ProtocolError(ValueError):
    """A packet that is not accepted; `reason` is one of REASONS."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


class Record(NamedTuple):
    device_id: int
    boot: int
    seq: int
    tick_ms: int  # device monotonic clock at the end of the averaging period
    age_ms: int  # time between tick_ms and transmission (resends carry a larger age)
    period_s: float  # averaging period
    values: tuple[float | None, ...]  # physical values in CHANNELS order, None = missing
    status: tuple[int, ...]  # status code per channel


def tag(key: bytes, body: bytes | memoryview) -> bytes:
    return hmac.digest(key, body, "sha256")[:TAG_LEN]


class Mac:
    """HMAC-SHA256 with the padded-key hash states computed once per device (3x faster than
    hmac.digest on the ingest hot path)."""

    __slots__ = ("_inner", "_outer")

    def __init__(self, key: bytes) -> None:
        if len(key) > 64:
            key = hashlib.sha256(key).digest()
        k = key.ljust(64, b"\0")
        self._inner = hashlib.sha256(bytes(b ^ 0x36 for b in k))
        self._outer = hashlib.sha256(bytes(b ^ 0x5C for b in k))

    def tag(self, body: bytes | memoryview) -> bytes:
        i = self._inner.copy()
        i.update(body)
        o = self._outer.copy()
        o.update(i.digest())
        return o.digest()[:TAG_LEN]


def to_raw(values: tuple[float | None, ...], status: tuple[int, ...]) -> list[int]:
    raw = []
    for i, (v, st) in enumerate(zip(values, status, strict=True)):
        if st >= 0x10 or v is None:
            raw.append(MISSING)
        else:
            raw.append(int(round(v / SCALES[i])))
    return raw


def encode_record(rec: Record, key: bytes) -> bytes:
    """Encode and authenticate one record (used by tests, the bench and the vector generator)."""
    chans: list[int] = []
    for r, st in zip(to_raw(rec.values, rec.status), rec.status, strict=True):
        chans += (r, st)
    body = _HEAD.pack(
        MAGIC,
        VERSION,
        TYPE_RECORD,
        rec.device_id,
        rec.boot,
        rec.seq,
        rec.tick_ms,
        rec.age_ms,
        int(round(rec.period_s * 10)),
    ) + _CHAN.pack(*chans)
    return body + tag(key, body)


def peek_device(data: bytes) -> int:
    """Check framing (size, magic, version, type) and return the device id, before any crypto."""
    n = len(data)
    if n < RECORD_LEN:
        raise ProtocolError("short", f"{n} bytes, expected {RECORD_LEN}")
    if n > RECORD_LEN:
        raise ProtocolError("long", f"{n} bytes, expected {RECORD_LEN}")
    if data[0:2] != MAGIC:
        raise ProtocolError("bad_magic", data[0:2].hex())
    if data[2] != VERSION:
        raise ProtocolError("bad_version", str(data[2]))
    if data[3] != TYPE_RECORD:
        raise ProtocolError("bad_type", str(data[3]))
    return int.from_bytes(data[4:8], "big")


def verify(data: bytes, key: bytes | Mac) -> None:
    body = data[:RECORD_BODY_LEN]
    good = key.tag(body) if isinstance(key, Mac) else tag(key, body)
    if not hmac.compare_digest(good, data[RECORD_BODY_LEN:]):
        raise ProtocolError("bad_tag")


_RAW_RANGES = tuple((lo * inv, hi * inv) for (lo, hi), inv in zip(RANGES, _SCALE_INV, strict=True))


def parse_fields(data: bytes) -> Record:
    """Decode the fields of an authenticated packet and check their meaning and ranges."""
    f = _BODY.unpack_from(data, 0)
    if f[8] == 0:
        raise ProtocolError("malformed", "averaging period 0")
    values: list[float | None] = []
    for i in range(7):
        raw, st = f[9 + 2 * i], f[10 + 2 * i]
        if st == 0 or st == ST_PARTIAL:
            lo, hi = _RAW_RANGES[i]
            if not lo <= raw <= hi:  # integer compare: no float rounding at the limits
                if raw == MISSING:
                    raise ProtocolError("malformed", f"{CHANNELS[i]}: missing value with status ok")
                v = raw / _SCALE_INV[i]
                raise ProtocolError("out_of_range", f"{CHANNELS[i]}={v:g} not in {RANGES[i]}")
            values.append(raw / _SCALE_INV[i])
        elif st in STATUS_NAMES:
            if raw != MISSING:
                raise ProtocolError("malformed", f"{CHANNELS[i]}: value sent with status {st:#x}")
            values.append(None)
        else:
            raise ProtocolError("malformed", f"{CHANNELS[i]}: unknown status 0x{st:02x}")
    return Record(f[3], f[4], f[5], f[6], f[7], f[8] / 10, tuple(values), f[10::2])


def decode_record(data: bytes, keys: Mapping[int, bytes]) -> Record:
    """Full check of one datagram: framing, device, tag, fields. Raises ProtocolError."""
    dev = peek_device(data)
    key = keys.get(dev)
    if key is None:
        raise ProtocolError("unknown_device", str(dev))
    verify(data, key)
    return parse_fields(data)


def encode_ack(
    device_id: int, boot: int, seq: int, status: int, reason: int, key: bytes | Mac
) -> bytes:
    body = _ACK.pack(MAGIC, VERSION, TYPE_ACK, device_id, boot, seq, status, reason)
    return body + (key.tag(body) if isinstance(key, Mac) else tag(key, body))


@dataclass(frozen=True, slots=True)
class Ack:
    device_id: int
    boot: int
    seq: int
    status: int
    reason: int


def decode_ack(data: bytes, key: bytes) -> Ack:
    if len(data) != ACK_LEN:
        raise ProtocolError("short" if len(data) < ACK_LEN else "long", f"{len(data)} bytes")
    magic, ver, typ, dev, boot, seq, st, reason = _ACK.unpack_from(data, 0)
    if magic != MAGIC:
        raise ProtocolError("bad_magic")
    if ver != VERSION:
        raise ProtocolError("bad_version")
    if typ != TYPE_ACK:
        raise ProtocolError("bad_type")
    if not hmac.compare_digest(tag(key, data[: _ACK.size]), data[_ACK.size :]):
        raise ProtocolError("bad_tag")
    if st not in (ACK_STORED, ACK_DUPLICATE, ACK_REJECTED):
        raise ProtocolError("malformed", f"ack status {st}")
    return Ack(dev, boot, seq, st, reason)


@dataclass(frozen=True, slots=True)
class BoardHealth:
    """The board's own counters since its boot (docs/wire-format.md, "Health packet")."""

    device_id: int
    boot: int
    hseq: int  # health packets of this boot, from 0: the replay check
    rssi_dbm: int | None  # Wi-Fi signal, None when unknown (UART, not connected)
    uptime_s: int
    records: int  # records made this boot (the next record's seq)
    dropped_full: int  # dropped from the ring: full
    dropped_old: int  # dropped from the ring: more than 512 seqs or 2**28 ms old
    sent: int  # transmissions, resends included
    acked: int  # records acknowledged stored or duplicate
    rejected: int  # records acknowledged rejected
    send_errors: int
    heap_free: int  # bytes
    ring: int  # records in the ring now

    @property
    def dropped(self) -> int:
        return self.dropped_full + self.dropped_old


def encode_health(h: BoardHealth, key: bytes | Mac) -> bytes:
    """Encode and authenticate one health packet (tests and the vector generator)."""
    body = _HEALTH.pack(MAGIC, VERSION, TYPE_HEALTH, h.device_id, h.boot, h.hseq, HEALTH_LAYOUT,
                        RSSI_UNKNOWN if h.rssi_dbm is None else h.rssi_dbm, h.uptime_s,
                        h.records, h.dropped_full, h.dropped_old, h.sent, h.acked, h.rejected,
                        h.send_errors, h.heap_free, h.ring)
    return body + (key.tag(body) if isinstance(key, Mac) else tag(key, body))


def is_health(data: bytes) -> bool:
    """Framing of a health packet (length and header), before any crypto."""
    return (len(data) == HEALTH_LEN and data[0:2] == MAGIC and data[2] == VERSION
            and data[3] == TYPE_HEALTH)


def verify_health(data: bytes, key: bytes | Mac) -> None:
    body = data[:HEALTH_BODY_LEN]
    good = key.tag(body) if isinstance(key, Mac) else tag(key, body)
    if not hmac.compare_digest(good, data[HEALTH_BODY_LEN:]):
        raise ProtocolError("bad_tag")


def parse_health(data: bytes) -> BoardHealth:
    """Decode an authenticated health packet and check it adds up. Every record a board made
    is in its ring, acknowledged, rejected or dropped, so records = ring + acked + rejected +
    dropped exactly; a packet where it does not is `malformed`."""
    f = _HEALTH.unpack_from(data, 0)
    if f[6] != HEALTH_LAYOUT:
        raise ProtocolError("malformed", f"health layout {f[6]}, this gateway knows "
                            f"{HEALTH_LAYOUT}")
    if f[7] > 0:
        raise ProtocolError("malformed", f"rssi {f[7]} dBm")
    h = BoardHealth(f[3], f[4], f[5], None if f[7] == RSSI_UNKNOWN else f[7], *f[8:])
    if h.records != h.ring + h.acked + h.rejected + h.dropped:
        raise ProtocolError("malformed", f"records {h.records} != ring {h.ring} + acked "
                            f"{h.acked} + rejected {h.rejected} + dropped {h.dropped}")
    return h

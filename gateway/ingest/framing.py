"""COBS framing (Cheshire & Baker 1999) for packets over a serial line: 0x00 ends a frame."""

from __future__ import annotations


class FramingError(ValueError):
    pass


def cobs_encode(data: bytes) -> bytes:
    out = bytearray([0])
    code_pos, code = 0, 1
    for b in data:
        if b == 0:
            out[code_pos] = code
            code_pos, code = len(out), 1
            out.append(0)
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_pos] = code
                code_pos, code = len(out), 1
                out.append(0)
    out[code_pos] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise FramingError("zero byte inside a COBS frame")
        end = i + code
        if end > n:
            raise FramingError("COBS code runs past the end of the frame")
        chunk = data[i + 1 : end]
        if 0 in chunk:
            raise FramingError("zero byte inside a COBS frame")
        out += chunk
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


class Deframer:
    """Splits a byte stream into frames; oversized garbage is discarded up to the next 0x00."""

    def __init__(self, max_frame: int = 512) -> None:
        self.max_frame = max_frame
        self._buf = bytearray()
        self._overflow = False

    def feed(self, data: bytes) -> list[bytes | FramingError]:
        out: list[bytes | FramingError] = []
        for chunk_end in _split_keep(data):
            part, done = chunk_end
            if not self._overflow:
                self._buf += part
                if len(self._buf) > self.max_frame:
                    self._overflow = True
                    self._buf.clear()
            if done:
                if self._overflow:
                    out.append(FramingError(f"frame longer than {self.max_frame} bytes"))
                elif self._buf:
                    try:
                        out.append(cobs_decode(bytes(self._buf)))
                    except FramingError as e:
                        out.append(e)
                self._buf.clear()
                self._overflow = False
        return out


def _split_keep(data: bytes) -> list[tuple[bytes, bool]]:
    parts = data.split(b"\0")
    return [(part, i < len(parts) - 1) for i, part in enumerate(parts)]

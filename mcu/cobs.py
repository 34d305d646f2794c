"""COBS framing for the UART link (same as gateway/ingest/framing.py): 0x00 ends a frame."""


def encode_into(src, n: int, dst) -> int:
    """Encode src[:n] into dst (>= n + n // 254 + 2 bytes) followed by the 0x00 delimiter;
    returns the number of bytes written, delimiter included. No allocation."""
    code_pos = 0
    code = 1
    o = 1
    for i in range(n):
        b = src[i]
        if b == 0:
            dst[code_pos] = code
            code_pos = o
            o += 1
            code = 1
        else:
            dst[o] = b
            o += 1
            code += 1
            if code == 0xFF:
                dst[code_pos] = code
                code_pos = o
                o += 1
                code = 1
    dst[code_pos] = code
    dst[o] = 0
    return o + 1


def decode(src, n: int, dst) -> int:
    """Decode one frame src[:n] (without its delimiter) into dst; returns its length, or -1 if
    the frame is not valid COBS."""
    i = 0
    o = 0
    while i < n:
        code = src[i]
        if code == 0:
            return -1
        end = i + code
        if end > n:
            return -1
        for j in range(i + 1, end):
            b = src[j]
            if b == 0 or o >= len(dst):
                return -1
            dst[o] = b
            o += 1
        i = end
        if code != 0xFF and i < n:
            if o >= len(dst):
                return -1
            dst[o] = 0
            o += 1
    return o

"""Fake `machine` for host tests: replays a sensor trace from the folder named by $SERRA_TRACE.

One text file per input, one reading per line, cycling at the end: adc_<gpio>.txt (raw counts),
pin_<gpio>.txt (0/1), dht_<gpio>.txt ("t rh", "timeout", "checksum" or "zero"). Files are read
line by line so the fake itself takes almost nothing from the emulated ESP32 heap. Only the
hardware edge is fake: the firmware above it is real.
"""

import os
from time import sleep_ms, ticks_add, ticks_diff, ticks_ms

from fake_watchdog import WDT, reset  # noqa: F401 (re-exported)

_cursors = {}


def _cursor(kind, pin_id, default):
    """One cursor per input: a driver that re-creates its sensor object continues the trace."""
    key = (kind, pin_id)
    if key not in _cursors:
        _cursors[key] = _Cursor(kind, pin_id, default)
    return _cursors[key]


class _Cursor:
    def __init__(self, kind, pin_id, default):
        root = os.getenv("SERRA_TRACE")
        self.path = f"{root}/{kind}_{pin_id}.txt" if root else None
        self.default = default
        self.f = None

    def next(self):
        if self.path is None:
            return self.default
        for _ in range(2):
            if self.f is None:
                try:
                    self.f = open(self.path)
                except OSError:
                    self.path = None
                    return self.default
            line = self.f.readline()
            if line:
                return line.strip()
            self.f.close()
            self.f = None  # cycle
        return self.default


# Only what the firmware uses: every name here costs heap in the heap measurement's fakes.
class Pin:
    IN = 1

    def __init__(self, id, mode=-1, pull=-1, value=None):
        self.id = id
        self._cur = _cursor("pin", id, "1")

    def value(self, v=None):
        if v is None:
            return int(self._cur.next())
        return None


class ADC:
    """An input's trace line is its voltage as raw counts (read_u16, full scale 65535). One line
    per sample: read_u16() takes the next line; read_uv() converts the line read_u16() took just
    before (a second conversion of the same input), or takes the next line if read alone.
    read_uv() is the chip's eFuse-calibrated reading: $SERRA_ADC_FULL_UV [uV] at full scale
    (3_100_000 unless set; chips differ by several per cent)."""

    ATTN_11DB = 3

    def __init__(self, pin, atten=None):
        self._cur = _cursor("adc", pin.id, "0")
        self._last = 0
        self._held = False  # _last taken by read_u16() and not yet converted by read_uv()
        self._full_uv = int(os.getenv("SERRA_ADC_FULL_UV") or "3100000")

    def atten(self, a):
        self._atten = a

    def read_u16(self):
        self._last = int(self._cur.next())
        self._held = True
        return self._last

    def read_uv(self):
        if not self._held:
            self._last = int(self._cur.next())
        self._held = False
        return self._last * self._full_uv // 65535


class UART:
    """A UART wired to a host pty: $SERRA_UART_<id> names the device file. any()/read() never
    block, like the ESP32's with timeout=0. TX is baud-limited as on the board: the line drains
    baudrate/10 bytes a second (8N1) from a 128-byte FIFO, the ESP32's; write() blocks until
    the bytes that do not fit have drained, txdone() tells when all have. The bytes reach the pty
    at once: only the time the board would spend is modelled, in integer ms (no heap use)."""

    _FIFO = 128

    def __init__(self, id, baudrate=115200, **kw):
        import select

        path = os.getenv("SERRA_UART_" + str(id))
        if not path:
            raise OSError(f"fake UART {id}: set SERRA_UART_{id} to a pty path")
        self._f = open(path, "r+b")
        self._poll = select.poll()
        self._poll.register(self._f, select.POLLIN)
        self._baud = baudrate
        self._idle_at = ticks_ms()  # tick at which the last byte written has left the line

    def _ready(self):
        for _ in self._poll.ipoll(0):  # ipoll: no allocation, so heap checks see the firmware's
            return True
        return False

    def any(self):
        return 1 if self._ready() else 0

    def read(self, n=1):
        out = bytearray()
        while len(out) < n and self._ready():
            out += self._f.read(1)
        return bytes(out) if out else None

    def readinto(self, buf):
        """Up to len(buf) bytes that are waiting; None if none (the board's timeout=0)."""
        if not self._ready():
            return None
        return self._f.readinto(buf)

    def _queued(self, now):
        """Bytes still in the FIFO at tick `now`."""
        left_ms = ticks_diff(self._idle_at, now)
        return (left_ms * self._baud + 9999) // 10000 if left_ms > 0 else 0

    def write(self, buf):
        n = len(buf)
        now = ticks_ms()
        over = self._queued(now) + n - self._FIFO
        if over > 0:  # the board's write() waits until the rest fits
            sleep_ms((over * 10000 + self._baud - 1) // self._baud)
        start = self._idle_at if ticks_diff(self._idle_at, now) > 0 else now
        self._idle_at = ticks_add(start, (n * 10000 + self._baud - 1) // self._baud)
        return self._f.write(buf)  # unbuffered (the unix port's files): no flush, which on a
        # tty is an fsync() that fails with EINVAL

    def txdone(self):
        return ticks_diff(self._idle_at, ticks_ms()) <= 0

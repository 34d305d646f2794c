"""Fake `machine` for host tests: replays a sensor trace from the folder named by $SERRA_TRACE.

One text file per input, one reading per line, cycling at the end: adc_<gpio>.txt (raw counts),
pin_<gpio>.txt (0/1), dht_<gpio>.txt ("t rh", "timeout", "checksum" or "zero"). Files are read
line by line so the fake itself takes almost nothing from the emulated ESP32 heap. Only the
hardware edge is fake: the firmware above it is real.
"""

import os

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


def UART(id, baudrate=115200, **kw):
    """The fake UART (fake_uart.py), loaded only when a UART is opened: compiling its source at
    `import machine` took heap the UDP runs of the heap measurement do not have to spare."""
    from fake_uart import UART

    return UART(id, baudrate, **kw)

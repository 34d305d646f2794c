"""Fake `machine` for the simulated kit: sensor inputs read from a time-indexed trace.

$SERRA_SIM_TRACE names a text file, one line per simulated minute:
``unix_t t_in rh_in t_out rh_out i_glob wind rain`` (``nan`` = the sensor failed). The simulated
time is $SERRA_SIM_EPOCH + (wall − $SERRA_SIM_ANCHOR) · $SERRA_TIME_SCALE, the same line the
gateway's scaled clock follows. Inputs are the kit's wiring of mcu/config.example.json: DHT22 on
GPIO 4 (inside) and 16 (outside), pyranometer ADC 34, anemometer ADC 35, rain detector GPIO 27;
raw readings are made with the calibration the kit config carries, so the firmware's own
conversions give back the simulated values.
"""

import os
from time import time_ns

from fake_watchdog import WDT, reset  # noqa: F401 (re-exported)

_SCALE = float(os.getenv("SERRA_TIME_SCALE") or "1")
_EPOCH = float(os.getenv("SERRA_SIM_EPOCH") or "0")
_ANCHOR = float(os.getenv("SERRA_SIM_ANCHOR") or "0")
DARK, W_PER_COUNT, MPS_PER_VOLT = 120, 0.0305, 20.0


class _Trace:
    """The current row of the trace at the simulated time (file read forward, one line ahead)."""

    def __init__(self, path):
        self.f = open(path) if path else None
        self.row = None
        self.next = self._read()

    def _read(self):
        line = self.f.readline() if self.f else ""
        if not line:
            return None
        return [float(x) for x in line.split()]

    def now(self):
        t = _EPOCH + (time_ns() / 1e9 - _ANCHOR) * _SCALE
        while self.next is not None and self.next[0] <= t:
            self.row, self.next = self.next, self._read()
        return self.row  # None before the first row: the sensors fail (not ready)


TRACE = _Trace(os.getenv("SERRA_SIM_TRACE"))


def value(col):
    """1 t_in, 2 rh_in, 3 t_out, 4 rh_out, 5 i_glob, 6 wind, 7 rain; NaN when absent."""
    row = TRACE.now()
    return row[col] if row is not None else float("nan")


class Pin:
    IN = 1

    def __init__(self, id, mode=-1, pull=-1, value=None):
        self.id = id

    def value(self, v=None):
        if v is None:  # the rain detector: active low
            r = value(7)
            return 0 if r == r and r > 0 else 1
        return None


class ADC:
    ATTN_11DB = 3

    def __init__(self, pin, atten=None):
        self.pin = pin.id

    def atten(self, a):
        pass

    def read_u16(self):
        if self.pin == 34:  # pyranometer: counts = dark + I / (W per count)
            i = value(5)
            return int(DARK + max(i, 0.0) / W_PER_COUNT) if i == i else 0
        w = value(6)  # anemometer: volts = wind / (m/s per volt)
        uv = max(w, 0.0) / MPS_PER_VOLT * 1_000_000 if w == w else 0.0
        return min(int(uv * 65535 / 3_100_000 + 0.5), 65534)

    def read_uv(self):
        return self.read_u16() * 3_100_000 // 65535

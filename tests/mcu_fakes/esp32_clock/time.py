"""Fake `time` with the ESP32's tick period, for the tests that need the clock to wrap: on the
board ticks_ms() wraps at 2**30 ms (12.4 days) and ticks_add/ticks_diff work modulo 2**30; the
unix port's period is 2**62, so on the host the firmware never sees a wrap. $SERRA_TICKS_START
sets the first reading (2**30 - 3000: the clock wraps 3 s after the interpreter starts).
Put this folder first on MICROPYPATH; everything else is the real clock.
"""

import os
import sys

from micropython import const

_path = sys.path
sys.path = []  # import the built-in module this file shadows
try:
    import time as _t
    from time import sleep, sleep_ms, sleep_us, time, time_ns  # noqa: F401  (re-exported)
finally:
    sys.path = _path

_MASK = const((1 << 30) - 1)
_HALF = const(1 << 29)
_START = int(os.getenv("SERRA_TICKS_START") or "0")
_T0 = _t.ticks_ms()


def ticks_ms():
    return (_t.ticks_diff(_t.ticks_ms(), _T0) + _START) & _MASK


def ticks_add(t, delta):
    return (t + delta) & _MASK


def ticks_diff(a, b):
    return ((a - b + _HALF) & _MASK) - _HALF

"""Fake `time` with the ESP32's tick period, first on MICROPYPATH in every firmware run of the
tests (tests/mcu_fakes/hostenv.py), so that no test depends on how long the host has been up.

The unix port's ticks_ms() is the host's CLOCK_MONOTONIC in ms (its uptime), with a period of
2**62: on a CI host up 24.8 days it is past 2**31, a value no board ever shows. On the board
ticks_ms() wraps at 2**30 ms (12.4 days) and ticks_add/ticks_diff work modulo 2**30. Here the
first reading is $SERRA_TICKS_START (hostenv sets it; 2**30 - 3000: the clock wraps 3 s after
the interpreter starts), and the clock runs at the real rate from there, whatever the host's.
$SERRA_TICKS_BITS sets the period (30, the ESP32's and every 32-bit port's, unless set; 62:
the unix port's own, to run the firmware as the unix port would on a host up that long, with
the port's own ticks_add and ticks_diff).
$SERRA_TICKS_RATE (an integer, 1 unless set) runs the board's clock that many times faster than
the host's, and shortens sleep_ms() and sleep_us() as much: a test whose point is a count of
records (an outage longer than the ring, the gateway's 512-record span) need not wait a real
0.1 s for each. (time() stays the host's: the firmware reads only ticks.)
Everything else is the real module.
"""

import os
import sys

_path = sys.path
sys.path = []  # import the built-in module this file shadows
try:
    import time as _t
    from time import sleep, time, time_ns  # noqa: F401  (re-exported)
finally:
    sys.path = _path

_BITS = int(os.getenv("SERRA_TICKS_BITS") or "30")
_MASK = (1 << _BITS) - 1
_HALF = 1 << (_BITS - 1)
_START = int(os.getenv("SERRA_TICKS_START") or "0")
_RATE = int(os.getenv("SERRA_TICKS_RATE") or "1")
_T0 = _t.ticks_us()


def ticks_ms():
    return (_t.ticks_diff(_t.ticks_us(), _T0) * _RATE // 1000 + _START) & _MASK


def sleep_us(us):
    _t.sleep_us(us // _RATE)


def sleep_ms(ms):
    _t.sleep_us(ms * 1000 // _RATE)


def ticks_add(t, delta):
    return (t + delta) & _MASK


def ticks_diff(a, b):
    return ((a - b + _HALF) & _MASK) - _HALF


if _t.ticks_add(0, -1) == _MASK:
    # The port's own period: its own (C) functions, which take only small ints as a board's do.
    ticks_add = _t.ticks_add
    ticks_diff = _t.ticks_diff

"""Fake `time` for the simulated kit: the real MicroPython clock sped up $SERRA_TIME_SCALE times.

The firmware runs unchanged with its real settings (60 s periods, DHT22 every 2 s, watchdog,
acks), one device minute passing in 1/scale of a wall minute; sleeps are shortened as much, but
never below $SERRA_MIN_SLEEP_US wall microseconds, so the loop does not spin a core. TEST/DEMO
ONLY: the gateway must run a clock scaled the same way (gateway/service/clock.py).
"""

import os
import sys

_path = sys.path
sys.path = []  # import the built-in module this file shadows
try:
    import time as _t
    from time import ticks_add, ticks_diff, time, time_ns  # noqa: F401  (re-exported)
finally:
    sys.path = _path

_SCALE = float(os.getenv("SERRA_TIME_SCALE") or "1")
_MIN_US = int(os.getenv("SERRA_MIN_SLEEP_US") or "2000")
_T0 = _t.time_ns()


def ticks_ms():
    return int((_t.time_ns() - _T0) * _SCALE / 1_000_000)


def ticks_us():
    return int((_t.time_ns() - _T0) * _SCALE / 1_000)


def sleep_us(us):
    _t.sleep_us(max(int(us / _SCALE), _MIN_US))


def sleep_ms(ms):
    sleep_us(ms * 1000)


def sleep(s):
    sleep_us(int(s * 1_000_000))

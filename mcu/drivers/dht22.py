"""DHT22 (AM2302) temperature/humidity through MicroPython's `dht` module.

Never reports a made-up value: a timeout, a bad checksum, the all-zero frame (0.0 degC, 0.0 %,
valid checksum, sent by a sensor whose bus glitched) and out-of-range answers are failures.
"""

from time import ticks_diff

import status
from micropython import const

MIN_INTERVAL_MS = const(2000)  # datasheet: at most one conversion every 2 s


class DHT22:
    def __init__(self, pin, dht_cls, reinit_after: int = 3) -> None:
        """pin: machine.Pin; dht_cls: dht.DHT22 (re-created after `reinit_after` failures in a
        row, which clears a hung bus)."""
        self._pin = pin
        self._cls = dht_cls
        self._dev = dht_cls(pin)
        self._reinit_after = reinit_after
        self._fails = 0
        self._last = 0
        self._fresh = True
        self.temperature = 0.0  # degC, valid only when status < 0x10
        self.humidity = 0.0  # %
        self.status = status.NOT_READY

    def read(self, now) -> int:
        """Convert if the 2 s minimum interval allows, else keep the last result (held value)."""
        if not self._fresh and ticks_diff(now, self._last) < MIN_INTERVAL_MS:
            return self.status
        self._fresh = False
        self._last = now
        st = status.OK
        try:
            self._dev.measure()
            t = self._dev.temperature()
            rh = self._dev.humidity()
            if t == 0 and rh == 0:
                st = status.CHECKSUM
            elif not (-40.0 <= t <= 80.0 and 0.0 <= rh <= 100.0):
                st = status.RANGE
            else:
                self.temperature = t
                self.humidity = rh
        except OSError:
            st = status.TIMEOUT
        except Exception:  # the dht module raises a plain Exception on a checksum error
            st = status.CHECKSUM
        if st == status.OK:
            self._fails = 0
        else:
            self._fails += 1
            if self._fails % self._reinit_after == 0:
                self._dev = self._cls(self._pin)
        self.status = st
        return st

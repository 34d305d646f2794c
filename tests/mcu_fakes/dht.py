"""Fake `dht`: each measure() takes the next trace line: "t rh", "timeout", "checksum" or
"zero" (the all-zero frame with a valid checksum that real DHT22s send after a bus glitch)."""

from machine import _cursor


class DHT22:
    def __init__(self, pin):
        self._cur = _cursor("dht", pin.id, "20.0 50.0")
        self._t = 0.0
        self._rh = 0.0

    def measure(self):
        v = self._cur.next()
        if v == "timeout":
            raise OSError(110)  # ETIMEDOUT, as dht_readinto raises
        if v == "checksum":
            raise Exception("checksum error")
        if v == "zero":
            self._t, self._rh = 0.0, 0.0
        else:
            t, rh = v.split()
            self._t, self._rh = float(t), float(rh)

    def temperature(self):
        return self._t

    def humidity(self):
        return self._rh

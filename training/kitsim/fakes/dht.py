"""Fake `dht` for the simulated kit: GPIO 4 reads the inside columns, GPIO 16 the outside ones;
a missing value (the simulator's failed read) is a bus timeout. measure() leaves the sensor's
frame (tenths) in `buf`, as MicroPython's dht.DHT22 does."""

from dht_frame import fill
from machine import value


class DHT22:
    def __init__(self, pin):
        self.cols = (1, 2) if pin.id == 4 else (3, 4)
        self.buf = bytearray(5)

    def measure(self):
        t, rh = value(self.cols[0]), value(self.cols[1])
        if t != t or rh != rh:
            raise OSError(110)  # ETIMEDOUT, as dht_readinto raises
        fill(self.buf, t, rh)

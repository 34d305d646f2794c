"""Fake `machine.UART` for host tests (machine.UART opens it)."""

import os
from time import sleep_ms, ticks_add, ticks_diff, ticks_ms


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

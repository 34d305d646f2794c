"""Per-period averaging of the seven channels with a status per channel."""

import status
from micropython import const

N_CHAN = const(7)  # t_in, rh_in, t_out, rh_out, i_glob, wind, rain
RAIN = const(6)
SCALE_INV = (100, 100, 100, 100, 10, 100, 1)  # raw int16 per unit, as in wire.py
MISSING = const(-32768)


class Averager:
    """Sums good reads, counts failures; finish() yields raw int16 values and statuses.

    A channel with no good read in the period is MISSING with its last error code; a channel with
    some failed reads is averaged over the good ones and flagged PARTIAL. Rain is the maximum
    (wet at any time in the period).
    """

    def __init__(self) -> None:
        self._sum = [0.0] * N_CHAN
        self._n = [0] * N_CHAN
        self._fail = [0] * N_CHAN
        self._err = [status.NOT_READY] * N_CHAN
        self.raw = [MISSING] * N_CHAN
        self.status = [status.NOT_READY] * N_CHAN

    def add(self, chan: int, value: float) -> None:
        if chan == RAIN:
            if value > self._sum[chan]:
                self._sum[chan] = value
        else:
            self._sum[chan] += value
        self._n[chan] += 1

    def fail(self, chan: int, code: int) -> None:
        self._fail[chan] += 1
        self._err[chan] = code

    def finish(self) -> None:
        """Fill self.raw/self.status for the period just ended and start a new one."""
        for i in range(N_CHAN):
            n = self._n[i]
            if n == 0:
                self.raw[i] = MISSING
                self.status[i] = self._err[i]
            else:
                v = self._sum[i] if i == RAIN else self._sum[i] / n
                r = int(round(v * SCALE_INV[i]))
                self.raw[i] = 32767 if r > 32767 else (-32767 if r < -32767 else r)
                self.status[i] = status.PARTIAL if self._fail[i] else status.OK
            self._sum[i] = 0.0
            self._n[i] = 0
            self._fail[i] = 0
            self._err[i] = status.NOT_READY

"""Rain detector board (comparator output on a digital pin): 1 = wet."""


import status


class RainDetector:
    def __init__(self, pin, active_low: bool = True) -> None:
        """pin: machine.Pin configured as input (most boards pull the output low when wet)."""
        self._pin = pin
        self._wet_level = 0 if active_low else 1
        self.value = 0
        self.status = status.NOT_READY

    def read(self) -> int:
        self.value = 1 if self._pin.value() == self._wet_level else 0
        self.status = status.OK
        return self.status

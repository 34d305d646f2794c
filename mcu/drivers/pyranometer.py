"""BPW34 photodiode pyranometer on an ADC input: W m-2 = (counts - dark) * w_per_count."""


import status


class Pyranometer:
    def __init__(self, adc, dark_counts: int, w_per_count: float, sat_counts: int = 65500) -> None:
        """adc: machine.ADC with its attenuation already set; calibration from the config."""
        self._adc = adc
        self._dark = dark_counts
        self._k = w_per_count
        self._sat = sat_counts
        self.value = 0.0
        self.status = status.NOT_READY

    def read(self) -> int:
        c = self._adc.read_u16()
        if c >= self._sat:
            self.status = status.SATURATED  # above the calibrated range: value unknown
        else:
            # Below the dark offset is noise at night, not negative light.
            self.value = (c - self._dark) * self._k if c > self._dark else 0.0
            self.status = status.OK
        return self.status

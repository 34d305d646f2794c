"""DC-motor cup anemometer on an ADC input: m s-1 = volts * mps_per_volt above a dead band."""


import status


class Anemometer:
    def __init__(self, adc, mps_per_volt: float, dead_band_v: float,
                 sat_uv: int = 3_100_000) -> None:
        """adc: machine.ADC (read_uv is the ESP32's calibrated reading)."""
        self._adc = adc
        self._k = mps_per_volt
        self._dead_uv = int(dead_band_v * 1_000_000)
        self._sat = sat_uv
        self.value = 0.0
        self.status = status.NOT_READY

    def read(self) -> int:
        uv = self._adc.read_uv()
        if uv >= self._sat:
            self.status = status.SATURATED
        else:
            # The motor needs a starting torque: below the dead band the voltage is noise.
            self.value = uv * self._k / 1_000_000 if uv > self._dead_uv else 0.0
            self.status = status.OK
        return self.status

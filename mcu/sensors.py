"""The measuring side: channel status codes, the sensor drivers, per-period averaging.

One module rather than one per driver: on the board every module costs RAM of its own (module
object, globals, interned file names), and the status codes below are compile-time constants
only inside the module that defines them.

Channel status codes (same as gateway/protocol.py ST_*, table in docs/wire-format.md); below
0x10 a value is present:
  0x00 ok, 0x01 partial (averaged over the good reads; some reads of the period failed),
  0x10 no_sensor (pin null in the config), 0x11 timeout (sensor did not answer),
  0x12 checksum (corrupted frame, including the all-zero DHT22 frame), 0x13 range (answered
  outside its physical range), 0x14 saturated (ADC at full scale), 0x15 not_ready (no read
  completed in the period).
"""

from time import ticks_diff

from micropython import const

_OK = const(0x00)
_PARTIAL = const(0x01)
_NO_SENSOR = const(0x10)
_TIMEOUT = const(0x11)
_CHECKSUM = const(0x12)
_RANGE = const(0x13)
_SATURATED = const(0x14)
_NOT_READY = const(0x15)

_MISSING = const(-32768)  # raw value of a channel without a value
_RAIN = const(6)  # channels: t_in, rh_in, t_out, rh_out, i_glob, wind, rain
# Each driver reads integer counts (DHT22 tenths, ADC counts, 10 uV) and gives `scale`, the
# wire's raw int16 units (wire-format.md: 0.01 degC, 0.01 %, 0.1 W m-2, 0.01 m s-1) per count:
# the period sums integers and converts once per record. A float per read would be a heap
# object per read on the ESP32. The upper ranges the gateway accepts (wire-format.md): it
# rejects a whole record for one value outside them, so such a read is flagged range by its
# driver and the other channels still arrive (the lower bounds, 0, are clamped by the dead
# band / dark offset; the DHT22's are checked in its driver).
_I_GLOB_MAX = 2000.0  # W m-2
_WIND_MAX = 75.0  # m s-1
_UV_PER_COUNT = const(10)  # the anemometer's count: a sum of 3460 full-scale reads fits a small int
# read_u16() at the ADC's full scale, whatever its width: the ESP32 port scales a raw count
# to 16 bits by repeating its bits (4095 of 12 bits -> 65535).
_FULL_U16 = const(65535)
_DHT_MIN_INTERVAL_MS = const(2000)  # datasheet: at most one conversion every 2 s


class DHT22:
    """DHT22 (AM2302) temperature/humidity through MicroPython's `dht` module.

    Never reports a made-up value: a timeout, a bad checksum, the all-zero frame (0.0 degC,
    0.0 %, valid checksum, sent by a sensor whose bus glitched) and out-of-range answers are
    failures.
    """

    def __init__(self, pin, dht_cls, reinit_after: int = 3) -> None:
        """pin: machine.Pin; dht_cls: dht.DHT22, re-created after `reinit_after` failures in a
        row. That is only a fresh object (a new 5-byte buffer, the same pin): it does not reset
        the sensor. Every measure() already sends the whole start signal (pin set open drain,
        250 ms high, 18 ms low). A DHT22 that stops answering is commonly brought back only by
        cutting its supply, which the firmware cannot do (the config has no pin switching it)."""
        self._pin = pin
        self._cls = dht_cls
        self._dev = dht_cls(pin)
        self._reinit_after = reinit_after
        self._fails = 0
        self._last = 0
        self._fresh = True
        self.t_tenths = 0  # 0.1 degC, valid only when status < 0x10
        self.rh_tenths = 0  # 0.1 %
        self.scale = 10  # wire units (0.01 degC, 0.01 %) per tenth
        self.status = _NOT_READY

    def read(self, now) -> int:
        """Convert if the 2 s minimum interval allows, else keep the last result (held value)."""
        if not self._fresh and ticks_diff(now, self._last) < _DHT_MIN_INTERVAL_MS:
            return self.status
        self._fresh = False
        self._last = now
        st = _OK
        try:
            self._dev.measure()
            # The frame as integer tenths (DHT22 datasheet; what dht.DHT22's temperature() and
            # humidity() decode into a float each): RH, then T with its sign in bit 15.
            b = self._dev.buf
            rh = b[0] << 8 | b[1]
            t = (b[2] & 0x7F) << 8 | b[3]
            if b[2] & 0x80:
                t = -t
            if t == 0 and rh == 0:
                st = _CHECKSUM
            elif not (-400 <= t <= 800 and 0 <= rh <= 1000):
                st = _RANGE
            else:
                self.t_tenths = t
                self.rh_tenths = rh
        except OSError:
            st = _TIMEOUT
        except Exception:  # the dht module raises a plain Exception on a checksum error
            st = _CHECKSUM
        if st == _OK:
            self._fails = 0
        else:
            self._fails += 1
            if self._fails % self._reinit_after == 0:
                self._dev = self._cls(self._pin)
        self.status = st
        return st


class Pyranometer:
    """BPW34 photodiode pyranometer on an ADC input: W m-2 = (counts - dark) * w_per_count."""

    def __init__(self, adc, dark_counts: int, w_per_count: float, sat: int = 65500) -> None:
        """adc: machine.ADC with its attenuation already set; calibration from the config;
        sat: counts at which the ADC is saturated."""
        self._adc = adc
        self._zero = dark_counts
        self._sat = sat
        # Counts above dark at the gateway's upper range (none above it if w_per_count <= 0).
        self._hi = int(_I_GLOB_MAX / w_per_count) if w_per_count > 0 else 0
        self.scale = w_per_count * 10  # wire units (0.1 W m-2) per count
        self.value = 0  # counts above dark
        self.status = _NOT_READY

    def read(self) -> int:
        c = self._adc.read_u16()
        if c >= self._sat:
            self.status = _SATURATED  # above the calibrated range: value unknown
            return self.status
        # Below the dark offset is noise at night, not negative light.
        c = c - self._zero if c > self._zero else 0
        if c > self._hi:
            self.status = _RANGE  # e.g. a pyranometer calibrated above 2000 W m-2
        else:
            self.value = c
            self.status = _OK
        return self.status


class Anemometer:
    """DC-motor cup anemometer on an ADC input: m s-1 = volts * mps_per_volt above a dead band."""

    def __init__(self, adc, mps_per_volt: float, dead_band_v: float,
                 sat: int = _FULL_U16) -> None:
        """adc: machine.ADC; sat: raw read_u16() count at which the ADC is saturated."""
        self._adc = adc
        self._zero = int(dead_band_v * 1_000_000) // _UV_PER_COUNT
        self._sat = sat
        # Counts at the gateway's upper range (none above it if mps_per_volt <= 0).
        self._hi = (int(_WIND_MAX / mps_per_volt * 1_000_000) // _UV_PER_COUNT
                    if mps_per_volt > 0 else 0)
        self.scale = mps_per_volt * _UV_PER_COUNT / 10_000  # wire units (0.01 m s-1) per count
        self.value = 0  # counts of 10 uV
        self.status = _NOT_READY

    def read(self) -> int:
        # Saturation on the raw count: read_uv() applies the chip's eFuse calibration, so its
        # full-scale reading differs from chip to chip (a fixed uV threshold is never reached
        # on one that reads low, and cuts real readings on one that reads high). The value
        # from read_uv(), a second conversion of the same input, keeps that calibration.
        if self._adc.read_u16() >= self._sat:
            self.status = _SATURATED
            return self.status
        c = self._adc.read_uv() // _UV_PER_COUNT
        # The motor needs a starting torque: below the dead band the voltage is noise.
        c = c if c > self._zero else 0
        if c > self._hi:
            self.status = _RANGE
        else:
            self.value = c
            self.status = _OK
        return self.status


class RainDetector:
    """Rain detector board (comparator output on a digital pin): 1 = wet."""

    def __init__(self, pin, active_low: bool = True) -> None:
        """pin: machine.Pin configured as input (most boards pull the output low when wet)."""
        self._pin = pin
        self._zero = 0 if active_low else 1  # the level that means wet
        self.value = 0
        self.scale = 1
        self.status = _NOT_READY

    def read(self) -> int:
        self.value = 1 if self._pin.value() == self._zero else 0
        self.status = _OK
        return self.status


def build(pins, cal):
    """(dht_in, dht_out, pyranometer, anemometer, rain) from the config's pins and calibration;
    None where not fitted."""
    import dht
    import machine

    def adc(n):
        a = machine.ADC(machine.Pin(n))
        a.atten(machine.ADC.ATTN_11DB)  # 0..3.1 V input range
        return a

    p = pins
    return (
        DHT22(machine.Pin(p["dht_in"]), dht.DHT22) if p["dht_in"] is not None else None,
        DHT22(machine.Pin(p["dht_out"]), dht.DHT22) if p["dht_out"] is not None else None,
        Pyranometer(adc(p["pyranometer"]), cal["pyr_dark_counts"], cal["pyr_w_per_count"])
        if p["pyranometer"] is not None else None,
        Anemometer(adc(p["anemometer"]), cal["wind_mps_per_volt"], cal["wind_dead_band_v"])
        if p["anemometer"] is not None else None,
        RainDetector(machine.Pin(p["rain"], machine.Pin.IN), cal["rain_active_low"])
        if p["rain"] is not None else None,
    )


class Averager:
    """Sums good reads (integer counts), counts failures; finish() yields raw int16 values and
    statuses.

    A channel with no good read in the period is missing (raw -32768) with its last error code;
    a channel with some failed reads is averaged over the good ones and flagged partial. Rain is
    the maximum (wet at any time in the period).
    """

    def __init__(self) -> None:
        self._sum = [0] * 7
        self._n = [0] * 7
        self._fail = [0] * 7
        self._err = [_NOT_READY] * 7
        self._scale = [1] * 7  # raw int16 units per count, from the channel's driver
        self.raw = [_MISSING] * 7
        self.status = [_NOT_READY] * 7

    def add(self, chan: int, count: int, scale) -> None:
        """A good read: `count` in its driver's integer unit, `scale` raw units per count."""
        if chan == _RAIN:
            if count > self._sum[chan]:
                self._sum[chan] = count
        else:
            self._sum[chan] += count
        self._n[chan] += 1
        self._scale[chan] = scale

    def fail(self, chan: int, code: int) -> None:
        self._fail[chan] += 1
        self._err[chan] = code

    def sample(self, sensors, now) -> None:
        """Read every sensor once (a DHT22 holds its last result for 2 s) into the period."""
        for i in range(5):
            drv = sensors[i]
            # Channels: DHT22 inside -> 0 and 1, outside -> 2 and 3; then 4, 5, 6.
            c = 2 * i if i < 2 else i + 2
            if drv is None:
                self.fail(c, _NO_SENSOR)
                if i < 2:
                    self.fail(c + 1, _NO_SENSOR)
            elif i < 2:
                if drv.read(now) == _OK:
                    self.add(c, drv.t_tenths, drv.scale)
                    self.add(c + 1, drv.rh_tenths, drv.scale)
                else:
                    self.fail(c, drv.status)
                    self.fail(c + 1, drv.status)
            elif drv.read() == _OK:
                self.add(c, drv.value, drv.scale)
            else:
                self.fail(c, drv.status)

    def finish(self) -> None:
        """Fill self.raw/self.status for the period just ended and start a new one."""
        for i in range(7):
            n = self._n[i]
            if n == 0:
                self.raw[i] = _MISSING
                self.status[i] = self._err[i]
            else:
                v = self._sum[i] if i == _RAIN else self._sum[i] / n
                r = int(round(v * self._scale[i]))
                self.raw[i] = 32767 if r > 32767 else (-32767 if r < -32767 else r)
                self.status[i] = _PARTIAL if self._fail[i] else _OK
            self._sum[i] = 0
            self._n[i] = 0
            self._fail[i] = 0
            self._err[i] = _NOT_READY

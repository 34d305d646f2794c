"""Channel status codes, shared with gateway/protocol.py (ST_*). Below 0x10 a value is present."""

from micropython import const

OK = const(0x00)
PARTIAL = const(0x01)  # averaged over the good reads; some reads of the period failed
NO_SENSOR = const(0x10)  # channel not fitted (pin null in the config)
TIMEOUT = const(0x11)  # sensor did not answer
CHECKSUM = const(0x12)  # corrupted frame, including the all-zero DHT22 frame
RANGE = const(0x13)  # answered outside its physical range
SATURATED = const(0x14)  # ADC at full scale
NOT_READY = const(0x15)  # no read completed in this period

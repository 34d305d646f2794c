"""The DHT22's 5-byte frame, as the sensor sends it and MicroPython's dht.DHT22 keeps it in
`buf`: RH and T in tenths (big-endian), T's sign in bit 7 of byte 2, then the checksum. Shared by
the firmware tests' fake `dht` and the simulated kit's."""


def fill(buf, t, rh):
    """Write the frame of t [degC] and rh [%] (rounded to the sensor's 0.1, within what its
    fields hold: a simulated RH below 0 is sent as 0) into buf."""
    rh10 = min(max(int(round(rh * 10)), 0), 0xFFFF)
    t10 = min(int(round(abs(t) * 10)), 0x7FFF)
    buf[0] = rh10 >> 8
    buf[1] = rh10 & 0xFF
    buf[2] = (t10 >> 8) | (0x80 if t < 0 else 0)
    buf[3] = t10 & 0xFF
    buf[4] = (buf[0] + buf[1] + buf[2] + buf[3]) & 0xFF

"""Packets over a UART (a board on the gateway's USB port): COBS frames, 0x00 delimited."""

from cobs import decode, encode_into
from wire import ACK_LEN, HEALTH_LEN, RECORD_LEN


class UartPort:
    def __init__(self, uart) -> None:
        """uart: machine.UART already configured (baud rate, pins)."""
        self.uart = uart
        self._tx = bytearray(RECORD_LEN + 2)  # a record's frame: COBS adds 1 byte, then 0x00
        self._htx = bytearray(HEALTH_LEN + 2)  # a health packet's (74 bytes: fits the 128 FIFO)
        self._rx = bytearray(2 * ACK_LEN)  # a frame in progress
        self._n = 0
        self._ack = bytearray(ACK_LEN)
        self._b = bytearray(1)  # readinto() it: read(1) would allocate a bytes per byte
        self.bad_frames = 0

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def ready(self) -> bool:
        """The previous frame has left: write() takes the next whole without blocking.

        write() blocks while the frame does not fit in the TX buffer (the ESP32's FIFO is 128
        bytes, a frame 65): at 1200 baud a burst of 8 frames, written at once, stalled the
        sampling loop 4.4 s. One frame in flight at a time never blocks and keeps the line
        busy but for the loop's <= 10 ms sleep between frames."""
        return self.uart.txdone()

    def send(self, buf) -> None:
        tx = self._tx if len(buf) == RECORD_LEN else self._htx
        n = encode_into(buf, len(buf), tx)
        # A packet fills its buffer: written whole, no memoryview slice allocated per frame.
        self.uart.write(tx if n == len(tx) else memoryview(tx)[:n])

    def recv(self):
        """One decoded frame if complete, else None (never blocks)."""
        u = self.uart
        while u.any():
            if not u.readinto(self._b):
                return None
            b = self._b[0]
            if b != 0:
                if self._n < len(self._rx):
                    self._rx[self._n] = b
                self._n += 1  # an overlong frame is counted and dropped at its delimiter
                continue
            n, self._n = self._n, 0
            if n == 0:
                continue
            if n > len(self._rx):
                self.bad_frames += 1
                continue
            m = decode(self._rx, n, self._ack)
            if m == ACK_LEN:
                return self._ack
            self.bad_frames += 1
        return None


def from_config(cfg) -> UartPort:
    """The UartPort on the configured UART (the board's default pins when tx/rx are -1)."""
    import machine

    if cfg.uart_tx >= 0 and cfg.uart_rx >= 0:
        return UartPort(machine.UART(cfg.uart_id, baudrate=cfg.uart_baud, tx=cfg.uart_tx,
                                     rx=cfg.uart_rx))
    return UartPort(machine.UART(cfg.uart_id, baudrate=cfg.uart_baud))

"""Wi-Fi as a state machine with exponential backoff (never a reboot loop when the network is
gone) and the sender: resends records from the ring until an authenticated ack arrives."""

import socket
from time import ticks_add, ticks_diff

import wire
from micropython import const

_DOWN = const(0)
_CONNECTING = const(1)
UP = const(2)
BACKOFF = const(3)


class WifiLink:
    def __init__(self, wlan, ssid: str, password: str, timeout: int = 15000, bmin: int = 1000,
                 bmax: int = 60000, fail: tuple = ()) -> None:
        """timeout: ms per connection attempt; bmin/bmax: backoff bounds (ms); fail:
        wlan.status() codes that end an attempt early (network.STAT_NO_AP_FOUND,
        STAT_WRONG_PASSWORD, STAT_CONNECT_FAIL)."""
        self.wlan = wlan
        self.fail = fail
        self.ssid = ssid
        self.password = password
        self.timeout = timeout
        self.bmin = bmin
        self.bmax = bmax
        self.backoff = bmin
        self.state = _DOWN
        self.t = 0

    def step(self, now) -> bool:
        """Advance the state machine without blocking; True when the link is up."""
        s = self.state
        w = self.wlan
        if s == _DOWN:
            w.active(True)
            try:
                w.connect(self.ssid, self.password)
            except OSError:
                pass  # treated like a timeout below
            self.state = _CONNECTING
            self.t = now
            return False
        if s == BACKOFF:
            if ticks_diff(now, self.t) >= 0:
                self.state = _DOWN
            return False
        if w.isconnected():
            if s == _CONNECTING:
                self.state = UP
                self.backoff = self.bmin
            return True
        # UP and the link dropped, or CONNECTING and it failed or timed out: back off.
        if s == UP or ticks_diff(now, self.t) >= self.timeout or w.status() in self.fail:
            try:
                w.disconnect()
            except OSError:
                pass
            self.state = BACKOFF
            self.t = ticks_add(now, self.backoff)
            self.backoff = min(self.backoff * 2, self.bmax)
        return False


class UdpPort:
    """Datagrams to the gateway over Wi-Fi (non-blocking socket)."""

    def __init__(self, host: str, port: int) -> None:
        self.host = host
        self.port = port
        self.sock: socket.socket | None = None
        self.addr: tuple[str, int] | tuple[str, int, int, int] | None = None

    def open(self) -> None:
        if self.sock is None:
            self.addr = socket.getaddrinfo(self.host, self.port)[0][-1]
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.setblocking(False)
            self.sock = s

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def ready(self) -> bool:
        return True  # a non-blocking socket: a full buffer raises EAGAIN, counted as an error

    def send(self, buf) -> None:
        if self.sock is not None and self.addr is not None:
            self.sock.sendto(buf, self.addr)

    def recv(self):
        if self.sock is None:
            return None
        try:
            return self.sock.recv(64)
        except OSError:
            return None  # EAGAIN: nothing waiting


class Sender:
    """Sends due records from the ring through a port (UdpPort or UartPort) and removes those
    the gateway acknowledged. The packet is rebuilt in one buffer for each transmission."""

    def __init__(self, ring, mac, dev: int, boot: int, period_ds: int, port, rto: int,
                 burst: int = 8) -> None:
        """rto: ack timeout (ms) before the first resend."""
        self.ring = ring
        self.mac = mac
        self.dev = dev
        self.boot = boot
        self.period_ds = period_ds
        self.port = port
        self.rto = rto
        self.burst = burst
        self.tx = bytearray(wire.RECORD_LEN)
        self.sent = 0
        self.acked = 0
        self.rejected = 0
        self.errors = 0
        self._held = False
        self._retry = 0  # tick before which a failed open() is not tried again
        self._hold = rto  # ms, doubles per failed open() up to 60 s

    def close(self) -> None:
        self.port.close()

    def step(self, now) -> None:
        if self._held:
            if ticks_diff(now, self._retry) < 0:
                return
            self._held = False
        try:
            self.port.open()
        except OSError:
            # A gateway host name that does not resolve: on the board each lookup can block for
            # seconds, so not again on the next 10 ms loop: back off, 1, 2, 4 .. x the ack
            # timeout up to 60 s.
            self.errors += 1
            self._held = True
            self._retry = ticks_add(now, self._hold)
            self._hold = min(self._hold * 2, 60000)
            return
        self._hold = self.rto
        self._poll_acks()
        ring = self.ring
        tx = self.tx
        n = 0
        for i in range(ring.capacity):
            if n >= self.burst:
                break
            if ring.seq[i] < 0 or ticks_diff(now, ring.due[i]) < 0:
                continue
            if not self.port.ready():
                break  # the link is still sending: the rest go on later passes, still due
            wire.pack_head(tx, self.dev, self.boot, ring.seq[i], ring.tick[i], self.period_ds)
            tx[26:47] = ring.slot(i)  # the channels, after the 26-byte header
            wire.seal(tx, ticks_diff(now, ring.tick[i]), self.mac)
            try:
                self.port.send(tx)
                self.sent += 1
            except OSError:
                self.errors += 1
            # Backoff per record: 1, 2, 4, 8x the ack timeout, so an outage does not flood.
            tries = ring.tries[i]
            ring.tries[i] = tries + 1 if tries < 255 else 255
            ring.due[i] = ticks_add(now, self.rto << (tries if tries < 3 else 3))
            n += 1

    def _poll_acks(self) -> None:
        for _ in range(32):
            data = self.port.recv()
            if data is None:
                return
            r = wire.parse_ack(data, self.dev, self.mac)
            if r is None or r[0] != self.boot:
                continue  # forged, garbled or from another boot: ignore
            if self.ring.remove(r[1]):
                if r[2] == wire.ACK_REJECTED:
                    self.rejected += 1
                    print("serra: record", r[1], "rejected by gateway, reason", r[3])
                else:
                    self.acked += 1

"""Health packets: the board's own counters (records made, dropped from the ring, sent, acked,
send errors, free heap, uptime, Wi-Fi RSSI), so the gateway learns of a drop without waiting
for the seq span (docs/wire-format.md, "Health packet"). Sent at boot + 1 min, then every
health_s, and once the link is up after the ring dropped records (at most once a minute).
Never acknowledged: each packet carries the totals since boot, so a lost one costs nothing."""

import gc
from time import ticks_add, ticks_diff

import wire
from micropython import const

_SOON_MS = const(60000)  # first packet after boot; least time between drop-triggered ones


class Health:
    def __init__(self, now, every_ms: int) -> None:
        self.every = every_ms
        self.soon = min(_SOON_MS, every_ms)
        self.due = ticks_add(now, self.soon)
        self.last = now
        self.hseq = 0  # health packets this boot: the gateway's replay check
        self.told = 0  # ring.dropped in the last packet
        # Uptime accumulated each loop, as ticks wrap (2**30 ms on the ESP32); in s plus ms, so
        # it stays a small int (31 bits there: 12.4 days in ms) and adds never allocate.
        self.up_s = 0
        self.up_rem_ms = 0
        self.up_tick = now
        self.buf = bytearray(wire.HEALTH_LEN)
        self.c = [0] * 10

    def due_now(self, now, dropped: int) -> bool:
        ms = self.up_rem_ms + ticks_diff(now, self.up_tick)
        self.up_tick = now
        self.up_s += ms // 1000
        self.up_rem_ms = ms % 1000
        return ticks_diff(now, self.due) >= 0 or (
            dropped != self.told and ticks_diff(now, self.last) >= self.soon)

    def send(self, now, sender, records: int, rssi: int) -> None:
        """Build, print and send one packet through the sender's port (open: link up)."""
        ring = sender.ring
        c = self.c
        c[0] = self.up_s
        c[1] = records
        c[2] = ring.dropped - ring.dropped_old
        c[3] = ring.dropped_old
        c[4] = sender.sent
        c[5] = sender.acked
        c[6] = sender.rejected
        c[7] = sender.errors
        c[8] = gc.mem_free()
        c[9] = ring.count
        if not -127 <= rssi <= 0:
            rssi = -128  # unknown
        wire.seal_health(self.buf, sender.mac, sender.dev, sender.boot, self.hseq, rssi, c)
        # The console line the host tests compare with what the gateway stored.
        print("HEALTH", self.hseq, "records", c[1], "dropped", ring.dropped, "full", c[2],
              "old", c[3], "sent", c[4], "acked", c[5], "rejected", c[6], "errors", c[7],
              "heap", c[8], "ring", c[9], "rssi", rssi, "uptime", c[0])
        try:
            sender.port.send(self.buf)
        except OSError:
            sender.errors += 1
        self.hseq += 1
        self.told = ring.dropped
        self.last = now
        self.due = ticks_add(now, self.every)

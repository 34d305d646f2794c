"""RAM ring of records not yet acknowledged: fixed slots, no allocation per record.

A slot keeps only what changes from record to record: the seven channels (CHAN_LEN = 21 bytes)
plus the sequence number and tick in typed arrays. The rest of the packet (device, boot,
period) is the same for the whole boot; the sender rebuilds the 63 bytes just before each
(re)transmission, when the age and the tag have to be written anyway. 128 records: 4.4 KB.

When full, the oldest record is dropped (and counted): fresh data is worth more than old. A
record older than `max_span` sequence numbers is dropped too, so in-flight sequence numbers stay
within the gateway's replay window (1024) even if one record keeps getting lost. A record older
than 2**28 ms (3.1 days; reachable with a long period and a big ring) is dropped as well: on the
ESP32 ticks wrap at 2**30 and ticks_diff() measures only up to 2**29 ms, past which its age
would come out negative and the gateway would date it weeks off.
"""

from array import array
from time import ticks_diff

from micropython import const
from wire import CHAN_LEN

_FREE = const(-1)
_MAX_AGE_MS = const(1 << 28)  # plus one period (<= 6553 s) and a resend, still below 2**29
# The gateway counts the records dropped here from the seqs alone, with this and max_span
# (gateway/store/losses.py; tests/test_board_losses.py runs this ring against it).


class Ring:
    def __init__(self, capacity: int = 128, max_span: int = 512) -> None:
        self.capacity = capacity
        self.max_span = max_span
        self.mv = memoryview(bytearray(capacity * CHAN_LEN))
        # Typed arrays, not lists: no boxed ints on the heap. Sequence numbers restart every
        # boot: int32. Ticks are small ints below the port's tick period: 2**30 on the ESP32,
        # 2**62 on the unix port (the simulated kit, the host tests), where they pass 2**31
        # after 24.8 days of its clock (the host's uptime), and an int32 cuts them short. A C
        # long is the port's word (4 bytes on the ESP32, 8 on the unix port): every tick fits,
        # and reads back as the small int ticks_diff() needs ("q" would give a long int, which
        # ticks_diff() misreads, and allocate at every read).
        from struct import calcsize

        w = calcsize("l")
        self.seq = array("i", bytearray(4 * capacity))  # -1 (free) or the record's seq
        for i in range(capacity):
            self.seq[i] = _FREE
        self.tick = array("l", bytearray(w * capacity))  # tick at the end of the record's period
        self.due = array("l", bytearray(w * capacity))  # tick of the next (re)transmission
        self.tries = bytearray(capacity)
        self.count = 0
        self.dropped = 0  # all drops; the health packet splits them: full, too old
        self.dropped_old = 0

    def push(self, seq: int, tick):
        """Reserve a slot for a new record; returns its channel bytes (a CHAN_LEN memoryview)."""
        slot = -1
        too_old = seq - self.max_span
        for i in range(self.capacity):
            s = self.seq[i]
            if s != _FREE and (s <= too_old or ticks_diff(tick, self.tick[i]) > _MAX_AGE_MS):
                self.seq[i] = _FREE
                self.count -= 1
                self.dropped += 1
                self.dropped_old += 1
        if self.count == self.capacity:
            oldest = 0
            for i in range(self.capacity):
                if self.seq[i] < self.seq[oldest]:
                    oldest = i
            slot = oldest
            self.dropped += 1
            self.count -= 1
        else:
            for i in range(self.capacity):
                if self.seq[i] == _FREE:
                    slot = i
                    break
        self.seq[slot] = seq
        self.tick[slot] = tick
        self.due[slot] = tick
        self.tries[slot] = 0
        self.count += 1
        return self.slot(slot)

    def slot(self, i: int):
        return self.mv[i * CHAN_LEN:(i + 1) * CHAN_LEN]

    def remove(self, seq: int) -> bool:
        for i in range(self.capacity):
            if self.seq[i] == seq:
                self.seq[i] = _FREE
                self.count -= 1
                return True
        return False

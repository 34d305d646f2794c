"""RAM ring of records not yet acknowledged: fixed slots, no allocation per record.

When full, the oldest record is dropped (and counted): fresh data is worth more than old. A
record older than `max_span` sequence numbers is dropped too, so in-flight sequence numbers stay
within the gateway's replay window (1024) even if one record keeps getting lost.
"""

from array import array

from micropython import const
from wire import RECORD_LEN

FREE = const(-1)


class Ring:
    def __init__(self, capacity: int = 128, max_span: int = 512) -> None:
        self.capacity = capacity
        self.max_span = max_span
        self.buf = bytearray(capacity * RECORD_LEN)
        self.mv = memoryview(self.buf)
        # Typed arrays, not lists: no boxed ints on the heap. Ticks wrap below 2**30: int32.
        self.seq = array("q", [FREE] * capacity)  # FREE or the record's sequence number
        self.tick = array("i", [0] * capacity)  # device tick at the end of the record's period
        self.due = array("i", [0] * capacity)  # tick of the next (re)transmission
        self.tries = array("B", [0] * capacity)
        self.count = 0
        self.dropped = 0

    def push(self, seq: int, tick):
        """Reserve a slot for a new record; returns its memoryview (RECORD_LEN bytes)."""
        slot = -1
        too_old = seq - self.max_span
        for i in range(self.capacity):
            if self.seq[i] != FREE and self.seq[i] <= too_old:
                self.seq[i] = FREE
                self.count -= 1
                self.dropped += 1
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
                if self.seq[i] == FREE:
                    slot = i
                    break
        self.seq[slot] = seq
        self.tick[slot] = tick
        self.due[slot] = tick
        self.tries[slot] = 0
        self.count += 1
        return self.mv[slot * RECORD_LEN:(slot + 1) * RECORD_LEN]

    def slot_view(self, i: int):
        return self.mv[i * RECORD_LEN:(i + 1) * RECORD_LEN]

    def remove(self, seq: int) -> bool:
        for i in range(self.capacity):
            if self.seq[i] == seq:
                self.seq[i] = FREE
                self.count -= 1
                return True
        return False

"""Counters by reason and a rate-limited logger, so a flood of bad packets cannot fill the disk."""

from __future__ import annotations

import logging
import time
from collections import Counter


class RateLimitedLog:
    """At most `burst` messages per key per `interval` seconds; then one summary line."""

    def __init__(self, logger: logging.Logger, interval: float = 10.0, burst: int = 5,
                 clock=time.monotonic) -> None:
        self.log = logger
        self.interval = interval
        self.burst = burst
        self.clock = clock
        self._win: dict[str, list] = {}  # key -> [window start, emitted, suppressed]

    def warning(self, key: str, msg: str, *args: object) -> bool:
        now = self.clock()
        w = self._win.get(key)
        if w is None or now - w[0] >= self.interval:
            if w is not None and w[2]:
                self.log.warning("%d more '%s' messages suppressed in the last %.0f s",
                                 w[2], key, now - w[0])
            w = self._win[key] = [now, 0, 0]
        if w[1] < self.burst:
            w[1] += 1
            self.log.warning(msg, *args)
            return True
        w[2] += 1
        return False


class Counters(Counter[str]):
    """Packet counts by outcome: 'stored', 'duplicate', and every rejection reason."""

    def snapshot(self) -> dict[str, int]:
        return dict(sorted(self.items()))

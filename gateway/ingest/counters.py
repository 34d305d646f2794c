"""Counters by reason and a rate-limited logger, so a flood of bad packets cannot fill the disk."""

from __future__ import annotations

import logging
import time
from collections import Counter


class RateLimitedLog:
    """At most `burst` messages per (reason, device) per `interval` seconds; then one summary.

    Per device, so a flood of forged packets naming one device does not hide the warning for
    another (a real board flashed with a wrong key). At most `max_keys` windows are kept: past
    that, new devices share one window per reason, so random device ids cannot grow memory.
    """

    def __init__(self, logger: logging.Logger, interval: float = 10.0, burst: int = 5,
                 clock=time.monotonic, max_keys: int = 256) -> None:
        self.log = logger
        self.interval = interval
        self.burst = burst
        self.clock = clock
        self.max_keys = max_keys
        # (reason, "" | " for device N" | " for other devices") -> [start, emitted, suppressed]
        self._win: dict[tuple[str, str], list] = {}
        self._next_sweep = float("-inf")

    def _label(self, reason: str, device: int | None, now: float) -> tuple[str, str]:
        label = (reason, "" if device is None else f" for device {device}")
        if label in self._win or len(self._win) < self.max_keys:
            return label
        # Full: drop the windows that have run out, at most one sweep per interval (a flood of
        # new device ids must not cost a scan per packet).
        if now >= self._next_sweep:
            self._next_sweep = now + self.interval
            for old, w in list(self._win.items()):
                if now - w[0] >= self.interval:
                    self._flush(old, w, now)
                    del self._win[old]
            if len(self._win) < self.max_keys:
                return label
        return reason, " for other devices"

    def _flush(self, label: tuple[str, str], w: list, now: float) -> None:
        if w[2]:
            self.log.warning("%d more '%s' messages%s suppressed in the last %.0f s",
                             w[2], label[0], label[1], now - w[0])

    def warning(self, reason: str, msg: str, *args: object, device: int | None = None) -> bool:
        now = self.clock()
        label = self._label(reason, device, now)
        w = self._win.get(label)
        if w is None or now - w[0] >= self.interval:
            if w is not None:
                self._flush(label, w, now)
            w = self._win[label] = [now, 0, 0]
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

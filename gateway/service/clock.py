"""The gateway clock: what time the gateway stamps samples with and runs its schedule by.

In service it is the wall clock. For tests and demos only, :class:`ScaledClock` runs ``scale``
times faster from a chosen ``epoch``, for a simulated kit whose own clock is sped up as much (the
real firmware under MicroPython with a scaled ``time`` module, training/kitsim): it sends one
record per *gateway* minute while 1/scale of a wall minute passes, so the estimator still sees
minute steps and 30 minutes of link cut last seconds. The kit's ages and periods are then already
in gateway time, and a record is stamped ``t = t_recv − age`` as always; network latency is
magnified by ``scale`` (1 ms of delay is 0.3 s of gateway time at 300×), so a record near a minute
boundary may land in the next minute. Every stored time is on this clock; retention too. The
anchor (wall time at which the clock read ``epoch``) is saved in the store, so a restarted
gateway continues the same time line instead of jumping back.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Protocol

log = logging.getLogger("serra.gateway")


class Clock(Protocol):
    @property
    def scale(self) -> float: ...  # read-only: the clocks are frozen dataclasses

    def now(self) -> float:
        """Gateway time [unix s]."""
        ...


@dataclass(frozen=True)
class WallClock:
    scale: float = 1.0

    def now(self) -> float:
        return time.time()


@dataclass(frozen=True)
class ScaledClock:
    """TEST/DEMO ONLY: ``epoch + (wall − anchor) · scale``."""

    epoch: float
    anchor: float
    scale: float

    def now(self) -> float:
        return self.epoch + (time.time() - self.anchor) * self.scale


def make_clock(scale: float, epoch: float | None, anchor: float | None,
               saved: dict[str, str]) -> tuple[Clock, dict[str, str]]:
    """The clock for the config, and the meta rows to save so a restart continues it.

    ``saved``: the meta rows a previous run left (``clock_epoch``, ``clock_scale``,
    ``clock_anchor``); they are reused when epoch and scale are unchanged and no anchor is set.
    """
    if scale == 1.0 and epoch is None:
        return WallClock(), {}
    assert epoch is not None
    same = saved.get("clock_epoch") == repr(epoch) and saved.get("clock_scale") == repr(scale)
    if anchor is None:
        anchor = float(saved["clock_anchor"]) if same and "clock_anchor" in saved else time.time()
    clock = ScaledClock(epoch, anchor, scale)
    log.warning("TEST/DEMO clock: gateway time runs %g× the wall clock from %s (now %s)", scale,
                time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(epoch)),
                time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(clock.now())))
    return clock, {"clock_epoch": repr(epoch), "clock_scale": repr(scale),
                   "clock_anchor": repr(anchor)}

"""The store's capacity alarms said without flooding the journal when space is short.

The ingest maintenance measures the store (``retention.capacity_alarms``) every round, 10 s:
each round logged its alarms, so a filling SD card wrote ``only N MB free`` 360 times an hour
into the journal on that card. Now each alarm (the database near its size limit, the disk
short of free space) is said when it starts, again when it is ``REMIND_S`` old or has got worse
by a step (the free space halved, the database grown by ``SIZE_STEP`` of its limit, since it
was last said), and once when it clears.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("serra.store.retention")

REMIND_S = 600.0  # [s] between lines of an alarm that lasts and does not get worse
SIZE_STEP = 0.05  # the database's growth, as a fraction of its limit, said at once


@dataclass(frozen=True)
class Alarm:
    """One capacity alarm: ``kind`` ("size" or "free"), the measured ``value`` (the database's
    fraction of its limit, or free bytes) and its line."""

    kind: str
    value: float
    text: str


@dataclass
class _Said:
    value: float  # when last said
    at: float  # [clock s] when last said


class CapacityWatch:
    """Says each alarm when it starts, while it lasts (reminder, a step worse) and when it
    clears; ``check`` once per maintenance round."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._said: dict[str, _Said] = {}

    def check(self, alarms: list[Alarm], cleared: dict[str, str]) -> None:
        """``alarms``: this round's; ``cleared``: for each kind, the line said when it stops."""
        now = self.clock()
        for a in alarms:
            said = self._said.get(a.kind)
            if said is None:
                log.warning("%s", a.text)
            elif _worse(a, said.value):
                log.warning("%s (worse)", a.text)
            elif now - said.at >= REMIND_S:
                log.warning("%s (for %.0f min now)", a.text, (now - said.at) / 60)
            else:
                continue
            self._said[a.kind] = _Said(a.value, now)
        for kind in [k for k in self._said if k not in {a.kind for a in alarms}]:
            del self._said[kind]
            log.warning("%s", cleared[kind])


def _worse(a: Alarm, said: float) -> bool:
    if a.kind == "free":  # free bytes halved
        return a.value <= said / 2
    return a.value >= said + SIZE_STEP  # the database's fraction of its limit grew a step


def cleared_lines(db_path: Path, max_db_bytes: int, alarm_fraction: float,
                  min_free_bytes: int) -> dict[str, str]:
    """The line of each alarm when it clears."""
    return {"size": f"database {db_path} is below {100 * alarm_fraction:.0f} % of its limit "
                    f"({max_db_bytes / 1e6:.0f} MB) again",
            "free": f"disk of {db_path} has {min_free_bytes / 1e6:.0f} MB free or more again"}

"""The estimator's check of each kit sample: values it must not learn from are dropped.

A value is dropped (NaN) and counted per column and reason when it is missing, outside the kit
column's possible range (gateway/kitcsv.py ``COLUMNS``) or, for the inside temperature, stuck:
the same reading repeated bit for bit ``STUCK_SAMPLES`` times in a row (``stuck_limit``).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass

import numpy as np

from gateway.kitcsv import COLUMNS

STUCK_SAMPLES = 30
"""An inside temperature repeated bit for bit this many samples in a row (30 min at 1 min) is a
stuck sensor: real air temperature, read to 0.01 °C, always moves within half an hour. When the
run is recognised, the repeats already accepted are struck out and the parameters fitted to them
are rolled back (``OnlineEstimator._strike_stuck_run``)."""




def stuck_limit(step: float, native_step: float | None = None) -> int:
    """Samples on a ``step`` [s] grid that ``STUCK_SAMPLES`` identical readings of the data's
    own rows, ``native_step`` [s] apart, span: 30 at 1 min on 1-minute rows, 146 on a 60 s grid
    of 5-minute rows (interpolating between equal rows repeats their value 5 times; a coarse
    reading, 0.1 °C, of still air stays the same for an hour, and counting grid samples called
    that stuck). Never fewer than ``STUCK_SAMPLES``."""
    if native_step is None or native_step <= step:
        return STUCK_SAMPLES
    return max(STUCK_SAMPLES, int(round((STUCK_SAMPLES - 1) * native_step / step)) + 1)


@dataclass
class StuckRun:
    """The current run of identical inside temperatures; stuck from ``limit`` in a row on."""

    value: float = float("nan")
    length: int = 0
    limit: int = STUCK_SAMPLES

    def see(self, v: float) -> bool:
        """Count ``v``; True from the ``limit``-th identical value in a row on."""
        self.length = self.length + 1 if v == self.value else 1
        self.value = v
        return self.length >= self.limit


def check_sample(sample: Mapping[str, float], requires: Collection[str], stuck: StuckRun,
                 fault_counts: dict[str, int]) -> tuple[dict[str, float], list[str]]:
    """The sample's kit values (a dropped one as NaN) and the columns dropped as faults.

    A missing value is a fault only for a column the model ``requires`` (absent ones count as
    missing too); every fault is counted in ``fault_counts`` as ``column:reason``."""
    values: dict[str, float] = {}
    faults: list[str] = []

    def fault(name: str, reason: str) -> None:
        faults.append(name)
        key = f"{name}:{reason}"
        fault_counts[key] = fault_counts.get(key, 0) + 1

    for name, raw in sample.items():
        col = COLUMNS.get(name)
        if col is None:
            continue  # not a kit measurement (time stamps, ids)
        try:
            v = float(raw)
        except (TypeError, ValueError):
            v = np.nan
        reason = None
        if not np.isfinite(v):
            reason = "missing"
        elif not col.lower <= v <= col.upper:
            reason = "out_of_range"
        if name == "t_in" and reason is None and stuck.see(v):
            reason = "stuck"
        if reason is not None:
            v = np.nan
            if reason != "missing" or name in requires:
                fault(name, reason)
        values[name] = v
    for name in requires:
        if name not in values:
            values[name] = np.nan
            fault(name, "missing")
    return values, faults

"""The estimator's check of each kit sample: values it must not learn from are dropped.

A value is dropped (NaN) and counted per column and reason when it is missing, outside the kit
column's possible range (gateway/kitcsv.py ``COLUMNS``) or, for the inside temperature, stuck:
repeated bit for bit ``STUCK_SAMPLES`` times in a row.
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


@dataclass
class StuckRun:
    """The current run of identical inside temperatures."""

    value: float = float("nan")
    length: int = 0

    def see(self, v: float) -> bool:
        """Count ``v``; True from the ``STUCK_SAMPLES``-th identical value in a row on."""
        self.length = self.length + 1 if v == self.value else 1
        self.value = v
        return self.length >= STUCK_SAMPLES


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

"""What the online estimator gives out (gateway/estimate/online.py): the ``Prediction`` of each
sample and the running ``Counters`` of the replay report and the health page."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Prediction:
    """What ``OnlineEstimator.update`` returns for the sample at t.

    ``t_in``: predicted inside temperature at t + 1 [°C] (None when it cannot be made);
    ``theta``: parameters in force for that prediction (k,); ``estimated``: outputs whose group
    ran at this step; ``faults``: columns of this sample that were dropped; ``dead_reckoning``:
    True when the measured T_in[t] was missing and the previous prediction served as state.
    """

    t_in: float | None
    theta: np.ndarray
    estimated: tuple[str, ...] = ()
    faults: tuple[str, ...] = ()
    dead_reckoning: bool = False


@dataclass
class Counters:
    """Counts for the replay report and the gateway's health page."""

    samples: int = 0
    faulty_samples: int = 0  # samples with at least one dropped value
    faults: dict[str, int] = field(default_factory=dict)  # per column and reason
    estimated: dict[str, int] = field(default_factory=dict)  # per group
    skipped: dict[str, int] = field(default_factory=dict)  # group due but window incomplete
    no_prediction: int = 0

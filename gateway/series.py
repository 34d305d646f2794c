"""Regular-grid time series: kit samples resampled to the model step, gaps kept as gaps."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from gateway.kitcsv import KitCsvError, KitData, read_kit_csv

MAX_GAP_S = 300.0
"""No value is interpolated across a hole longer than this [s] (docs/data-format.md)."""
JITTER = 1.5
"""Two samples up to this multiple of the data's median spacing apart are neighbours, not a
hole, when that is longer than ``MAX_GAP_S`` and the step [-]: a logger whose clock jitters
(5-minute rows ±20 s) would otherwise turn every late sample into a gap, while one missing row
(twice the spacing) still is one."""
CLOCK_SLACK = 1.1
"""Data are refused as too coarse for the step only when their median spacing exceeds the
interpolation limit by more than this factor [-]: a kit that sleeps 300 s and takes a few
seconds to measure and send (rows every 305 s), or jittered rows whose median lands at 320 s,
are 5-minute data, not data to read at ``--step 305``."""
SAMPLINGS = ("instant", "mean")
"""What a row holds: the value at its time, or the mean over its step (the kit's minute
aggregates); the model reads the two differently (gateway/model/drivers.py, docs/model.md)."""


class TooCoarseError(KitCsvError):
    """Rows further apart than the tools interpolate across on the asked step: ``native`` [s]
    (their median spacing) and ``step`` [s] let a command that cannot change its step (the
    virtual sensor reads minutes) say so in its own words."""

    def __init__(self, message: str, native: float, step: float) -> None:
        super().__init__(message)
        self.native, self.step = native, step


@dataclass
class Series:
    """Samples on a regular grid of ``step`` seconds; NaN marks a gap or a missing value."""

    time: np.ndarray  # datetime64[s], UTC
    step: float  # [s]
    columns: dict[str, np.ndarray]
    source: str = "<memory>"
    notices: list[str] = field(default_factory=list)
    sampling: str = "instant"
    """``instant``: each value is the one at its time; ``mean``: each value is the mean over the
    step it starts (per-minute aggregates), see SAMPLINGS."""
    native_step: float | None = None
    """[s] Median spacing of the rows the series was resampled from (None: not resampled, the
    rows are the grid's): 5-minute rows on a 60 s grid repeat one reading over 5 samples."""

    def __post_init__(self) -> None:
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"sampling must be one of {SAMPLINGS}, got {self.sampling!r}")

    def __len__(self) -> int:
        return len(self.time)

    def __contains__(self, name: str) -> bool:
        return name in self.columns and bool(np.isfinite(self.columns[name]).any())

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def slice(self, start: int, stop: int) -> Series:
        """Rows ``start:stop`` as a new series sharing no arrays with this one."""
        return Series(
            self.time[start:stop].copy(),
            self.step,
            {k: v[start:stop].copy() for k, v in self.columns.items()},
            self.source,
            list(self.notices),
            self.sampling,
            self.native_step,
        )

    def index_of(self, stamp: np.datetime64) -> int:
        """Index of the first grid time at or after ``stamp``."""
        # numpy's stubs have no datetime64(datetime64, unit) overload; numpy takes it
        return int(np.searchsorted(self.time, np.datetime64(stamp, "s")))  # type: ignore[call-overload]


def resample(data: KitData, step: float = 60.0, max_gap: float = MAX_GAP_S) -> Series:
    """Resample irregular kit samples onto a grid of ``step`` seconds.

    Each grid value is interpolated linearly between the two neighbouring finite samples of its
    column, only when those are at most ``max_gap`` seconds apart (or the grid time falls on a
    sample); otherwise it stays NaN. A hole of one grid step is no hole at that grid, so the
    limit is at least ``step``; nor is a late or early sample of jittered rows, so it is also at
    least ``JITTER`` × the median spacing of the data. Samples finer than the grid are
    block-averaged first, so 30 s sensor noise is not aliased. Data sampled more coarsely than
    ``max_gap`` and ``step`` (by more than ``CLOCK_SLACK``) is an error: the tools do not
    bridge 10-minute rows on a 1-minute grid.
    """
    if step <= 0:
        raise ValueError(f"step must be positive, got {step}")
    t = data.seconds()
    start = np.ceil(t[0] / step) * step
    grid = start + step * np.arange(int(np.floor((t[-1] - start) / step + 1e-9)) + 1)
    native = float(np.median(np.diff(t))) if len(t) > 1 else step
    max_gap = max(max_gap, step)
    if native > CLOCK_SLACK * max_gap:
        raise TooCoarseError(
            f"{data.source}: samples are {native:g} s apart (median), more than the {max_gap:g} s "
            f"the tools interpolate across: on a {step:g} s grid almost every value would be a "
            f"gap; use a model step of at least {native:g} s (--step {native:g})", native, step)
    max_gap = max(max_gap, JITTER * native)
    columns = {}
    for name, values in data.columns.items():
        ok = np.isfinite(values)
        tt, vv = t[ok], values[ok]
        if native < step and len(tt):
            tt, vv = _block_average(tt, vv, step)
        columns[name] = _interp_with_gaps(grid, tt, vv, max_gap)
    return Series(
        time=grid.astype(np.int64).astype("datetime64[s]"),
        step=float(step),
        columns=columns,
        source=data.source,
        notices=list(data.notices),
        native_step=native,
    )


def _block_average(t: np.ndarray, v: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the samples in each grid cell [k step - step/2, k step + step/2)."""
    key = np.floor(t / step + 0.5).astype(np.int64)
    cells, start = np.unique(key, return_index=True)
    sums = np.add.reduceat(v, start)
    counts = np.diff(np.append(start, len(v)))
    return cells * step, sums / counts


def _interp_with_gaps(grid: np.ndarray, t: np.ndarray, v: np.ndarray, max_gap: float) -> np.ndarray:
    out = np.full(len(grid), np.nan)
    if len(t) == 0:
        return out
    right = np.searchsorted(t, grid, side="left")
    exact = (right < len(t)) & (t[np.minimum(right, len(t) - 1)] == grid)
    inside = (right > 0) & (right < len(t))
    r = np.minimum(right, len(t) - 1)
    left = np.maximum(right - 1, 0)
    span = t[r] - t[left]
    ok = inside & (span <= max_gap)
    frac = np.where(span > 0, (grid - t[left]) / np.where(span > 0, span, 1.0), 0.0)
    out[ok] = (v[left] + frac * (v[r] - v[left]))[ok]
    out[exact] = v[r][exact]
    return out


DEFAULT_STEP = 60.0
"""[s] The model step of the tools when none is given and the rows allow it."""


def data_step(data: KitData, default: float = DEFAULT_STEP) -> float:
    """The model step [s] that suits the rows: ``default``, unless the rows are further apart
    than the tools interpolate across (``CLOCK_SLACK`` × ``MAX_GAP_S``): then their median
    spacing, to the whole minute (10- and 15-minute loggers; 601 s of jitter is 600 s)."""
    t = data.seconds()
    native = float(np.median(np.diff(t))) if len(t) > 1 else default
    if native <= CLOCK_SLACK * max(MAX_GAP_S, default):
        return default
    return max(60.0, 60.0 * round(native / 60.0))


def load_series(
    path: str, step: float | None = 60.0, required: Iterable[str] = (), sampling: str = "instant"
) -> Series:
    """Read a kit CSV and resample it to ``step`` seconds (None: :func:`data_step`, the rows'
    own spacing when they are coarser than the tools interpolate across); ``sampling`` says
    whether its rows are instantaneous values or means over the step (SAMPLINGS)."""
    data = read_kit_csv(path, required=required)
    series = resample(data, data_step(data) if step is None else step)
    series.sampling = sampling
    series.__post_init__()
    return series

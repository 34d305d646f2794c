"""A heated house seen from the kit's data: the air held at a floor on cold nights (issue 10).

The kit reads the air, not the heating pipe. A heater a thermostat runs holds the air at a
floor near its setpoint whenever the house would otherwise cool below it, while the outside
keeps falling. An unheated house follows the outside: at night its air sits between the outside
(cover and leakage, together roughly 5 W m-2 K-1 of floor) and the floor and soil (a few
W m-2 K-1), so from one night to the next its late-night air moves by most of what the outside
moves, its steady-state share U_out / (U_out + U_soil) ≈ 0.6–0.9. A thermostat adds a gain G
far above both (a P band of 1–2 K over a heater of 100–150 W m-2: 60 W m-2 K-1 or more), which
cuts that share to about U_out / (U_out + U_soil + G) ≈ 0.1.

The statistic (no calibration, only the kit's t_in, t_out and i_glob):

1. nights: runs of dark samples (i_glob ≤ ``DARK_W_M2``) at least ``MIN_NIGHT_H`` long that end
   in the data (a night the record's end cuts is left out; short gaps are bridged);
2. each night's late part (its last ``LATE_FRACTION``, after the evening's stored heat has gone):
   the mean t_in and t_out over it (rows with both finite, at least ``MIN_VALID`` of them);
3. the colder ``COLD_FRACTION`` of the nights by that mean t_out (where a heater would work);
4. R = sd(late t_in) / sd(late t_out) over those nights [-]: the share of the outside's
   night-to-night swing the air follows, plus whatever else moves it (sun of the day before,
   wind, cloud), which only raises R: a small R needs the air held.

The air is held at a floor when R < ``MAX_RATIO`` and the cold nights' air is at least
``MIN_LIFT_K`` above the outside (a heater holds the air above it). Undecided (no hint) with
fewer than ``MIN_NIGHTS`` nights or cold nights whose outside swings less than
``MIN_SPREAD_K`` (nothing to follow). The constants were fixed before any measurement
(rule hh, docs/effects.md, "A heated house: the hint").
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from gateway.series import Series

DARK_W_M2 = 5.0
"""[W m-2] Global radiation at or below this is night (the kit's pyranometer reads 0-3 W m-2
in the dark; the vent controller's δ_sun uses the same threshold)."""
MIN_NIGHT_H = 6.0
"""[h] A night is a run of dark samples at least this long (a dull winter afternoon's dip is not)."""
MAX_GAP_H = 1.0
"""[h] A gap in i_glob up to this long between dark samples is dark (a lost reading or two)."""
LATE_FRACTION = 0.5
"""[-] The part of each night read: its last half, when the house has lost the day's stored
heat (mass time constant ≈ 2 h) and a thermostat, if any, holds it."""
MIN_VALID = 0.5
"""[-] A night counts when at least this fraction of its late part has finite t_in and t_out."""
MIN_NIGHTS = 8
"""Nights needed (the colder half then has at least 4): a 10-day record has 9-10."""
COLD_FRACTION = 0.5
"""[-] The nights read: this colder fraction by late-night mean t_out (rounded up)."""
MIN_SPREAD_K = 0.5
"""[K] Sample sd of the cold nights' late mean t_out needed to tell held from following."""
MIN_LIFT_K = 2.0
"""[K] Median of the cold nights' late mean t_in − t_out needed: a heater's floor is above the
outside."""
MAX_RATIO = 0.3
"""[-] R below this is a held floor: about the geometric mean of a heated house's ≈ 0.1 and an
unheated one's ≥ 0.6 (module docstring)."""


@dataclass
class HeatedFloor:
    """What the detector read; ``held`` is the verdict (False when undecided)."""

    held: bool
    nights: int
    """Nights with a valid late part."""
    cold_nights: int
    """Of them, the colder ones read (0 when undecided for too few nights)."""
    ratio: float | None
    """R [-]: sd of the cold nights' late mean t_in over that of t_out."""
    floor: float | None
    """[°C] Median of the cold nights' late mean t_in (near the setpoint when held)."""
    lift: float | None
    """[K] Median of the cold nights' late mean t_in − t_out."""
    spread: float | None
    """[K] Sample sd of the cold nights' late mean t_out."""
    reason: str
    """Why held or not, in words."""

    def to_json(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def night_runs(i_glob: np.ndarray, step: float) -> list[tuple[int, int]]:
    """(start, stop) index ranges of nights on a grid of ``step`` seconds: dark runs (i_glob ≤
    DARK_W_M2) at least MIN_NIGHT_H long whose end (the sunrise) is in the data.

    A gap of unknown radiation (NaN) up to MAX_GAP_H long is short: with dark on both sides it
    is dark (one lost reading does not split a night), and at the night's end it still shows the
    sunrise within it (the readings resume). A run that the record's end or a longer gap cuts
    short is left out: what it has is the early night, not the late part read.
    """
    known = np.isfinite(i_glob)
    dark = known & (np.nan_to_num(i_glob, nan=np.inf) <= DARK_W_M2)
    short = {a: b for a, b in _runs(~known)
             if 0 < a and b < len(dark) and (b - a) * step <= MAX_GAP_H * 3600}
    for a, b in short.items():
        if dark[a - 1] and dark[b]:
            dark[a:b] = True
    need = MIN_NIGHT_H * 3600.0 / step
    return [(a, b) for a, b in _runs(dark)
            if b - a >= need and b < len(dark) and (known[b] or b in short)]


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index ranges of the True runs of ``flags``."""
    edges = np.diff(np.concatenate(([0], flags.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def late_means(t_in: np.ndarray, t_out: np.ndarray, runs: list[tuple[int, int]]
               ) -> np.ndarray:
    """Rows (mean t_in, mean t_out) [°C] over each run's late part, runs with too few finite
    rows left out; shape (nights, 2)."""
    rows = []
    for a, b in runs:
        late = slice(b - math.ceil((b - a) * LATE_FRACTION), b)
        ti, to = t_in[late], t_out[late]
        ok = np.isfinite(ti) & np.isfinite(to)
        if ok.sum() >= MIN_VALID * len(ti) and ok.any():
            rows.append((float(ti[ok].mean()), float(to[ok].mean())))
    return np.array(rows, dtype=float).reshape(-1, 2)


def heated_floor(series: Series) -> HeatedFloor:
    """Whether ``series``' air is held at a floor on cold nights (module docstring)."""
    missing = [c for c in ("t_in", "t_out", "i_glob") if c not in series]
    if missing:
        return HeatedFloor(False, 0, 0, None, None, None, None,
                           f"no {', '.join(missing)} in the data")
    means = late_means(series["t_in"], series["t_out"], night_runs(series["i_glob"], series.step))
    n = len(means)
    if n < MIN_NIGHTS:
        return HeatedFloor(False, n, 0, None, None, None, None,
                           f"{n} nights of at least {MIN_NIGHT_H:g} h (needs {MIN_NIGHTS})")
    cold = means[np.argsort(means[:, 1], kind="stable")[:math.ceil(n * COLD_FRACTION)]]
    spread = float(np.std(cold[:, 1], ddof=1))
    ratio = float(np.std(cold[:, 0], ddof=1) / spread) if spread > 0 else None
    floor = float(np.median(cold[:, 0]))
    lift = float(np.median(cold[:, 0] - cold[:, 1]))
    args = (n, len(cold), ratio, floor, lift, spread)
    if ratio is None or spread < MIN_SPREAD_K:
        return HeatedFloor(False, *args, f"the cold nights' outside swings {spread:.2f} K "
                           f"(needs {MIN_SPREAD_K:g})")
    if lift < MIN_LIFT_K:
        return HeatedFloor(False, *args, f"the cold nights' air is {lift:.1f} K above the "
                           f"outside (a held floor needs {MIN_LIFT_K:g})")
    held = ratio < MAX_RATIO
    return HeatedFloor(held, *args, f"the air follows {ratio:.2f} of the outside's night-to-night "
                       f"swing over {len(cold)} cold nights: {'held' if held else 'following'} "
                       f"(held below {MAX_RATIO:g})")

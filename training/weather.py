"""Real measured outdoor weather shipped with Serra (Bleiswijk, NL, 2009; GreenLight 2.0.5).

``training/data/bleiswijk/`` holds the 5-minute file with its licence and source notes.
"""

from __future__ import annotations

import csv
import gzip
from pathlib import Path

import numpy as np

from gateway.model import psychrometrics as psy

BLEISWIJK = Path(__file__).parent / "data" / "bleiswijk" / "bleiswijk_weather_5min.csv.gz"
BLEISWIJK_START = np.datetime64("2009-10-20T00:00:00", "s")
"""Time zero of the file (local standard time, used here as UTC+01:00 → stored as UTC)."""


def load_bleiswijk(path: Path = BLEISWIJK) -> dict[str, np.ndarray]:
    """The Bleiswijk weather as arrays: ``time`` (datetime64[s], UTC), ``t_out`` [°C],
    ``rh_out`` [%] (from vpOut and tOut), ``i_glob`` [W m-2], ``wind`` [m s-1], ``t_sky`` [°C]."""
    with gzip.open(path, "rt", encoding="utf-8") as handle:
        rows = list(csv.reader(handle))
    header = rows[0]
    data = np.array(rows[3:], dtype=float)  # row 2: descriptions, row 3: units
    col = {name: data[:, i] for i, name in enumerate(header)}
    # The file counts from local standard time (CET = UTC+1).
    time = BLEISWIJK_START - np.timedelta64(3600, "s") + col["Time"].astype("timedelta64[s]")
    p_w = col["vpOut"] / 1000.0
    return {
        "time": time,
        "t_out": col["tOut"],
        "rh_out": np.clip(psy.relative_humidity(col["tOut"], p_w), 0.0, 100.0),
        "i_glob": np.maximum(col["iGlob"], 0.0),
        "wind": col["wind"],
        "t_sky": col["tSky"],
    }


def to_minutes(weather: dict[str, np.ndarray], step: float = 60.0) -> dict[str, np.ndarray]:
    """Linear interpolation of the 5-minute weather onto a ``step``-second grid."""
    t = weather["time"].astype(np.int64).astype(float)
    grid = t[0] + step * np.arange(int(np.floor((t[-1] - t[0]) / step + 1e-9)) + 1)
    out = {"time": grid.astype(np.int64).astype("datetime64[s]")}
    for name, values in weather.items():
        if name != "time":
            out[name] = np.interp(grid, t, values)
    return out

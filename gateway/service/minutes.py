"""A greenhouse's minutes from the store: inside columns from its inside kit, outside columns from
its outside kit, QC applied as ``export`` does; and which minutes are final.

A minute is final once every device of the greenhouse has stored a sample ``settle_s`` past its
end (records arrive in order; a resend rarely lags more), or, when a kit lags, ``max_wait_s``
after its end by the gateway clock. Records a kit kept while it was off and sends later are
stepped in order when they arrive: the estimator's cursor is the last minute it stepped, not
the clock.
"""

from __future__ import annotations

import math
import sqlite3
from dataclasses import dataclass

from gateway.store.export import DROP

INSIDE = ("t_in", "rh_in")
OUTSIDE = ("t_out", "rh_out", "i_glob", "wind", "rain")
KIT_COLUMNS = INSIDE + OUTSIDE
"""The kit CSV columns a Serra kit provides (docs/data-format.md)."""


@dataclass(frozen=True)
class Minute:
    minute: int  # start [unix s]
    values: dict[str, float]  # kit column → value, NaN when missing or QC-dropped


def _rows(conn: sqlite3.Connection, dev: int, cols: tuple[str, ...], start: int, stop: int
          ) -> dict[int, dict[str, float]]:
    sel = ", ".join(f"{c}, {c}_qc" for c in cols)
    out = {}
    for r in conn.execute(f"SELECT minute, {sel} FROM minute WHERE device_id=? AND minute>=? "
                          "AND minute<? ORDER BY minute", (dev, start, stop)):
        vals = {}
        for i, c in enumerate(cols):
            v, qc = r[1 + 2 * i], r[2 + 2 * i]
            v = math.nan if v is None or qc & DROP else float(v)
            if c == "rain" and not math.isnan(v):
                v = float(v > 0)
            vals[c] = v
        out[r[0]] = vals
    return out


def read_minutes(conn: sqlite3.Connection, inside: int, outside: int, start: int, stop: int
                 ) -> list[Minute]:
    """Minutes in [start, stop) that the inside kit has a row for, joined with the outside kit's
    row of the same minute (NaN where it has none), in time order."""
    ins = _rows(conn, inside, INSIDE, start, stop)
    outs = _rows(conn, outside, OUTSIDE, start, stop)
    nan = dict.fromkeys(OUTSIDE, math.nan)
    return [Minute(m, {**v, **outs.get(m, nan)}) for m, v in sorted(ins.items())]


def latest_sample_t(conn: sqlite3.Connection, device: int) -> float | None:
    """Time of the device's newest record (by boot and sequence: the primary key's order)."""
    r = conn.execute("SELECT t FROM samples WHERE device_id=? ORDER BY boot DESC, seq DESC "
                     "LIMIT 1", (device,)).fetchone()
    return r[0] if r else None


def final_before(conn: sqlite3.Connection, devices: set[int], now: float, settle_s: float,
                 max_wait_s: float) -> int:
    """Minutes starting before the returned time [unix s] and ending by it are final."""
    marks = [latest_sample_t(conn, d) for d in devices]
    heard = min((m - settle_s for m in marks if m is not None), default=-math.inf)
    if any(m is None for m in marks):
        heard = -math.inf
    bound = max(heard, now - max_wait_s)
    return int(bound // 60 * 60)


def first_minute(conn: sqlite3.Connection, inside: int) -> int | None:
    r = conn.execute("SELECT min(minute) FROM minute WHERE device_id=?", (inside,)).fetchone()
    return r[0]


def last_minute(conn: sqlite3.Connection, inside: int) -> int | None:
    r = conn.execute("SELECT max(minute) FROM minute WHERE device_id=?", (inside,)).fetchone()
    return r[0]

"""The latest health packet of each kit, as its board reported it (table ``board_health``,
store version 4; docs/wire-format.md, "Health packet"). Read by the status screen and the
``device/<id>`` message, beside the losses the gateway infers from seq gaps (losses.py)."""

from __future__ import annotations

import sqlite3
from dataclasses import asdict, dataclass
from typing import Any

_COLS = ("boot", "t_recv", "uptime_s", "records", "dropped_full", "dropped_old", "sent", "acked",
         "rejected", "send_errors", "heap_free", "ring", "rssi_dbm")


@dataclass(frozen=True)
class BoardReport:
    """Counters of the board's current boot (``boot`` as stored), received at ``t_recv``."""

    boot: int
    t_recv: float  # gateway clock [unix s]
    uptime_s: int
    records: int
    dropped_full: int  # dropped from the ring: full
    dropped_old: int  # dropped from the ring: too old
    sent: int
    acked: int
    rejected: int
    send_errors: int
    heap_free: int  # bytes
    ring: int
    rssi_dbm: int | None

    @property
    def dropped(self) -> int:
        return self.dropped_full + self.dropped_old


def latest(conn: sqlite3.Connection) -> dict[int, BoardReport]:
    """device → its latest report; empty for a store older than version 4 (read-only readers
    open such a store as it is)."""
    if conn.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'board_health'"
                    ).fetchone() is None:
        return {}
    return {r[0]: BoardReport(*r[1:]) for r in conn.execute(
        f"SELECT device_id, {', '.join(_COLS)} FROM board_health")}


def board_fields(r: BoardReport, stored_boot: int, board_boot: int | None) -> dict[str, Any]:
    """The report's fields for the ``device/<id>`` message, with ``board_boot``, its boot in the
    board's own counting (the stored boot minus its key's base, as the device's records')."""
    out = asdict(r)
    out["board_boot"] = r.boot - (stored_boot - board_boot if board_boot is not None else 0)
    return out

"""The live gateway's tables (schema 2, docs/store.md): writers for the service, readers for the
status screen and tools. Readers only run SELECTs, so they work on a read-only connection.

Writers marked "in the caller's transaction" never commit themselves: the service groups them
with the cursor they advance, so a crash leaves either all of a step or none of it.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from gateway.protocol import CHANNELS, STATUS_NAMES
from gateway.store.board_health import BoardReport, latest
from gateway.store.db import transaction
from gateway.store.losses import lost_by_device


@dataclass(frozen=True)
class EstimateRow:
    """One value the live gateway derived for a greenhouse at time t [unix s, gateway clock].

    ``source``/``name`` vocabulary (docs/store.md): ``measured``/``t_in``; ``online``/<parameter>
    and ``online``/``t_in_next``; ``forecast``/``t_in+<h>min`` (info: the outlook);
    ``flux``/<term>; ``vsensor``/``ventilation_flow``, ``ventilation_heat_loss`` (info:
    ``out_of_range`` when flagged)."""

    greenhouse: str
    t: float
    source: str
    name: str
    value: float | None
    unit: str = ""
    info: str = ""


def add_estimates(conn: sqlite3.Connection, rows: Iterable[EstimateRow]) -> None:
    """Insert estimate rows (in the caller's transaction)."""
    conn.executemany(
        "INSERT INTO estimates (t, source, name, value, unit, info, greenhouse) "
        "VALUES (?, ?, ?, ?, ?, ?, ?)",
        [(r.t, r.source, r.name, r.value, r.unit, r.info, r.greenhouse) for r in rows])


def save_greenhouses(conn: sqlite3.Connection, rows: Sequence[dict[str, Any]], now: float) -> None:
    """The config's greenhouses (name, farm, inside_device, outside_device, model, config)."""
    with transaction(conn):
        for r in rows:
            conn.execute(
                "INSERT OR REPLACE INTO greenhouses (name, farm, inside_device, outside_device, "
                "model, config, updated) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (r["name"], r["farm"], r["inside_device"], r["outside_device"], r["model"],
                 json.dumps(r["config"], default=str), now))


@dataclass(frozen=True)
class SavedState:
    model: str
    minute: int  # last minute stepped [unix s]: its rows are committed
    state: dict[str, Any]  # the snapshot as of ``minute``, or of the journal's ``snapshot``


def load_state(conn: sqlite3.Connection, greenhouse: str) -> SavedState | None:
    r = conn.execute("SELECT model, minute, state FROM estimator_state WHERE greenhouse=?",
                     (greenhouse,)).fetchone()
    return SavedState(r[0], r[1], json.loads(r[2])) if r else None


def save_state(conn: sqlite3.Connection, greenhouse: str, model: str, minute: int,
               state: dict[str, Any], now: float) -> None:
    """The estimator's snapshot and its cursor (in the caller's transaction); the journal of
    minutes stepped after an older snapshot is emptied."""
    conn.execute("INSERT OR REPLACE INTO estimator_state (greenhouse, model, minute, state, "
                 "updated) VALUES (?, ?, ?, ?, ?)",
                 (greenhouse, model, minute, json.dumps(state), now))
    conn.execute("DELETE FROM meta WHERE name=?", (_journal_key(greenhouse),))


@dataclass(frozen=True)
class Journal:
    """The minutes an estimator stepped after its saved snapshot, with the values it stepped
    them on: stepping them again from the snapshot gives the state at the cursor. ``snapshot``
    is the snapshot's last minute [unix s]; ``minutes`` are (minute [unix s], the values of
    ``columns`` in that order, NaN for missing)."""

    snapshot: int
    columns: tuple[str, ...]
    minutes: list[tuple[int, list[float]]]


def _journal_key(greenhouse: str) -> str:
    return f"estimator_journal/{greenhouse}"


def save_journal(conn: sqlite3.Connection, greenhouse: str, minute: int, journal: Journal) -> None:
    """Advance the saved cursor to ``minute`` without rewriting the snapshot: its journal in
    ``meta`` and the row's ``minute`` (one page of a row whose state spans ~40; in the
    caller's transaction)."""
    text = json.dumps({"snapshot": journal.snapshot, "columns": list(journal.columns),
                       "minutes": journal.minutes})  # repr floats and NaN: read back bit-exact
    key = _journal_key(greenhouse)
    # an UPDATE keeps the row's rowid: meta's page is written, not its key's index too
    if conn.execute("UPDATE meta SET value=? WHERE name=?", (text, key)).rowcount == 0:
        conn.execute("INSERT INTO meta (name, value) VALUES (?, ?)", (key, text))
    conn.execute("UPDATE estimator_state SET minute=? WHERE greenhouse=?", (minute, greenhouse))


def load_journal(conn: sqlite3.Connection, greenhouse: str) -> Journal | None:
    r = conn.execute("SELECT value FROM meta WHERE name=?", (_journal_key(greenhouse),)).fetchone()
    if r is None:
        return None
    j = json.loads(r[0])
    return Journal(int(j["snapshot"]), tuple(j["columns"]),
                   [(int(m), [float(v) for v in vs]) for m, vs in j["minutes"]])


def set_status(conn: sqlite3.Connection, items: dict[str, Any], now: float) -> None:
    """Gateway status rows (JSON values), e.g. ``gateway``, ``zenoh``, ``outbox``, ``ingest``."""
    with transaction(conn):
        conn.executemany("INSERT OR REPLACE INTO gateway_status (name, value, updated) "
                         "VALUES (?, ?, ?)",
                         [(k, json.dumps(v, default=str), now) for k, v in items.items()])


def read_status(conn: sqlite3.Connection) -> dict[str, tuple[Any, float]]:
    """name → (value, updated) of every gateway status row."""
    return {n: (json.loads(v), u) for n, v, u in
            conn.execute("SELECT name, value, updated FROM gateway_status")}


def latest_estimates(conn: sqlite3.Connection, greenhouse: str
                     ) -> dict[tuple[str, str], EstimateRow]:
    """(source, name) → the newest row of each, for one greenhouse."""
    rows = conn.execute("SELECT t, source, name, value, unit, info FROM estimates_latest "
                        "WHERE greenhouse=?", (greenhouse,))
    return {(r[1], r[2]): EstimateRow(greenhouse, *r) for r in rows}


def estimate_series(conn: sqlite3.Connection, greenhouse: str, name: str, since: float
                    ) -> list[tuple[float, float | None]]:
    """(t, value) of one estimate name since ``since`` (e.g. 24 h of ``t_in_next``)."""
    return list(conn.execute("SELECT t, value FROM estimates WHERE greenhouse=? AND name=? "
                             "AND t>=? ORDER BY t", (greenhouse, name, since)))


@dataclass(frozen=True)
class FindingRow:
    id: str
    greenhouse: str
    effect: str
    start: float | None
    first_seen: float
    last_seen: float
    revision: int
    published_revision: int
    detail: dict[str, Any]


def findings(conn: sqlite3.Connection, greenhouse: str | None = None) -> list[FindingRow]:
    sql = ("SELECT id, greenhouse, effect, start, first_seen, last_seen, revision, "
           "published_revision, detail FROM findings")
    args: tuple = ()
    if greenhouse is not None:
        sql, args = sql + " WHERE greenhouse=?", (greenhouse,)
    # one starred tuple: mypy counts a *r[:8] before another argument as unbounded (mypy#16677)
    return [FindingRow(*(*r[:8], json.loads(r[8])))
            for r in conn.execute(sql + " ORDER BY first_seen", args)]


@dataclass(frozen=True)
class DeviceHealth:
    """What the store knows about a kit: boot counter, records, last sample and its channels.

    ``boot`` is the boot as stored (the board's counter plus its key's boot base);
    ``board_boot`` is the board's own counter (docs/wire-format.md, "A reflashed or replaced
    board"); ``lost`` the records the board lost before they were stored, all boots
    (gateway/store/losses.py); ``board`` the counters of its latest health packet
    (gateway/store/board_health.py)."""

    device_id: int
    boot: int
    records: int
    first_seen: float
    last_seen: float
    last_sample_t: float | None
    channels: dict[str, str] = field(default_factory=dict)  # channel → status name
    board_boot: int | None = None
    lost: int = 0
    board: BoardReport | None = None  # its latest health packet (its own counters)


def boot_bases(conn: sqlite3.Connection) -> dict[int, list[int]]:
    """device → the boot bases of its keys (``meta`` rows ``boot_base/<device>/<key id>``)."""
    out: dict[int, list[int]] = {}
    for name, value in conn.execute("SELECT name, value FROM meta WHERE name LIKE 'boot_base/%'"):
        parts = name.split("/")
        if len(parts) == 3 and parts[1].isdigit():
            out.setdefault(int(parts[1]), []).append(int(value))
    return out


def board_boot(stored_boot: int, bases: list[int]) -> int:
    """The board's own boot counter of a stored boot: minus the highest key base not above it
    (a newer key's base is above every boot stored before it; an older key's packets are
    refused once a newer key has stored, so the stored boot is always of the highest base)."""
    return stored_boot - max((b for b in bases if b <= stored_boot), default=0)


def device_health(conn: sqlite3.Connection) -> list[DeviceHealth]:
    out = []
    cols = ", ".join(f"{c}_st" for c in CHANNELS)
    bases = boot_bases(conn)
    lost = lost_by_device(conn)
    reports = latest(conn)
    for dev, boot, n, first, last in conn.execute(
            "SELECT device_id, boot, n_samples, first_seen, last_seen FROM devices ORDER BY device_id"):
        r = conn.execute(f"SELECT t, {cols} FROM samples WHERE device_id=? "
                         "ORDER BY boot DESC, seq DESC LIMIT 1", (dev,)).fetchone()
        chans = {c: STATUS_NAMES.get(s, str(s)) for c, s in zip(CHANNELS, r[1:], strict=True)} if r else {}
        out.append(DeviceHealth(dev, boot, n, first, last, r[0] if r else None, chans,
                                board_boot(boot, bases.get(dev, [])), lost.get(dev, 0),
                                reports.get(dev)))
    return out


def outbox_backlog(conn: sqlite3.Connection) -> tuple[int, float | None]:
    """(unsent messages, observation time of the oldest unsent one)."""
    n, oldest = conn.execute("SELECT count(*), min(t) FROM outbox WHERE sent IS NULL").fetchone()
    return n, oldest

"""What a ``make run`` did, counted from the two stores (opened read-only) and the kit's log."""

from __future__ import annotations

import json
import math
import sqlite3
import textwrap
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from gateway.status.snapshot import Skill
from gateway.status.store_source import forecast_skill
from gateway.store import StoreError, open_readonly


@dataclass
class Summary:
    start: float  # gateway time the kit started [unix s]
    end: float  # gateway time at the end
    scale: float
    kit_records: int = 0  # records the firmware made (its REC lines)
    stored: int = 0  # records in the gateway's store
    estimated: int = 0  # minutes the estimator stepped
    made: int = 0  # messages the gateway made
    published: int = 0  # messages put on Zenoh
    measurements: int = 0  # of which measurement messages
    pending: int = 0  # messages still in the outbox
    received: int = 0  # messages the subscriber stored (once each)
    skill: list[Skill] = field(default_factory=list)
    findings: list[str] = field(default_factory=list)

    @property
    def minutes(self) -> float:
        return (self.end - self.start) / 60.0

    def lines(self, width: int = 80) -> list[str]:
        """The summary, wrapped to ``width`` columns."""
        out = []
        for line in self._lines():
            head = len(line) - len(line.lstrip()) + (10 if line.startswith("  ") else 2)
            out += textwrap.wrap(line, width, subsequent_indent=" " * head,
                                 break_on_hyphens=False) or [""]
        return out

    def _lines(self) -> list[str]:
        def hm(t: float) -> str:
            return time.strftime("%Y-%m-%d %H:%MZ", time.gmtime(t))

        out = [f"summary: {self.minutes:.0f} simulated minutes ({hm(self.start)} → {hm(self.end)}, "
               f"{self.scale:g}× the wall clock)",
               f"  records   made by the kit {self.kit_records} · stored by the gateway {self.stored}"
               f" · estimator minutes {self.estimated}",
               f"  messages  made {self.made} · published on Zenoh {self.published} "
               f"(measurements {self.measurements}) · received by the subscriber {self.received}"
               + (f" · {self.pending} still in the outbox" if self.pending else "")]
        scored = [s for s in self.skill if s.n]
        if scored:
            # one n when every horizon has as many scored forecasts, else each its own (a short
            # run scores more 15-min forecasts than 60-min ones)
            one = len({s.n for s in scored}) == 1
            out.append("  forecast  MAE " + " · ".join(
                f"{s.horizon_min} min {s.mae:.2f} °C (persistence {s.persistence_mae:.2f}"
                + ("" if one else f", n={s.n}") + ")" for s in scored)  # "n=": never wrapped
                + (f", n={scored[-1].n}" if one else ""))
        else:
            out.append("  forecast  no forecast scored yet (a forecast is scored once its time "
                       "has come: run longer)")
        out.append("  findings  " + ("; ".join(self.findings) if self.findings else
                                     "none (the diagnosis runs every 6 simulated hours, on at "
                                     "least half a day of data)"))
        return out

    def write_json(self, path: Path) -> None:
        """The summary as strict JSON: a horizon not scored yet (its MAE NaN) is ``null``, not
        the ``NaN`` that Python's json writes and JSON parsers (JavaScript's, jq 1.6) refuse."""
        d = asdict(self)
        d["minutes"] = self.minutes
        d["skill"] = [{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in s.items()}
                      for s in d["skill"]]
        path.write_text(json.dumps(d, indent=1, default=str, allow_nan=False))


def count(db: Path, sql: str, args: tuple = ()) -> int:
    """One number from a store, read-only; 0 when the file or table is not there yet."""
    if not db.exists():
        return 0
    try:
        conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
        try:
            return int(conn.execute(sql, args).fetchone()[0] or 0)
        finally:
            conn.close()
    except sqlite3.Error:
        return 0


def delivery(gateway_db: Path, cloud_db: Path) -> tuple[int, int]:
    """(published, received) messages now, for the progress line. The count that can only trail
    is read first: every message received was published before it, so reading the received
    count first and the published one after keeps received <= published however many move
    meanwhile (read the other way round, the messages both published and received between the
    two reads counted as received only: "published 421 · received 422"). One window stays: the
    gateway marks a batch sent just after putting it (gateway/publish/publisher.py), so a
    subscriber that commits before that mark is counted ahead of it for that moment."""
    received = count(cloud_db, "SELECT count(*) FROM messages")
    published = count(gateway_db, "SELECT count(*) FROM outbox WHERE sent IS NOT NULL")
    return published, received


class EstimateCount:
    """The estimate rows of ``greenhouse`` named ``name`` in the store ``db``, counted as a run
    goes: each call reads only the rows stored since the call before (``id`` above the last one
    seen), by the table's primary key. Store v5's one index leads with the time, so
    ``count(*) ... WHERE name=?`` walks all of it at every call (the settling polls 5 times a
    second). The same number while no estimate row is deleted (a run is far inside
    ``estimates_days``): a row committed after a call gets an id above every id it saw."""

    SQL = ("SELECT count(CASE WHEN greenhouse=? AND name=? THEN 1 END), max(id) FROM estimates "
           "WHERE id>?")

    def __init__(self, db: Path, greenhouse: str, name: str) -> None:
        self.db, self.greenhouse, self.name = db, greenhouse, name
        self.rows, self.last_id = 0, 0

    def __call__(self) -> int:
        """The count now; the one before when the store or its table is not there (yet)."""
        if not self.db.exists():
            return self.rows
        try:
            conn = sqlite3.connect(f"file:{self.db}?mode=ro", uri=True, timeout=30)
            try:  # one statement: the count and the last id of the same commit
                n, top = conn.execute(self.SQL, (self.greenhouse, self.name,
                                                 self.last_id)).fetchone()
            finally:
                conn.close()
        except sqlite3.Error:
            return self.rows
        if top is not None:
            self.rows, self.last_id = self.rows + n, top
        return self.rows


def summarise(gateway_db: Path, cloud_db: Path, kit_records: int, start: float, end: float,
              scale: float, greenhouse: str, device: int, estimated: int) -> Summary:
    """``estimated``: the greenhouse's ``t_in_next`` rows, the minutes its estimator stepped
    (:class:`EstimateCount`, kept by the caller as the run went)."""
    s = Summary(start, end, scale, kit_records=kit_records, estimated=estimated)
    try:
        conn = open_readonly(gateway_db)
    except StoreError:
        return s
    try:
        q = conn.execute
        s.stored = q("SELECT count(*) FROM samples WHERE device_id=?", (device,)).fetchone()[0]
        s.made = q("SELECT count(*) FROM outbox").fetchone()[0]
        s.published = q("SELECT count(*) FROM outbox WHERE sent IS NOT NULL").fetchone()[0]
        s.measurements = q("SELECT count(*) FROM outbox WHERE sent IS NOT NULL AND kind LIKE "
                           "'measurement/%'").fetchone()[0]
        s.pending = s.made - s.published
        horizons = sorted(int(n[5:-3]) for (n,) in q(  # one row a name: not a scan of estimates
            "SELECT name FROM estimates_latest WHERE greenhouse=? AND source='forecast'",
            (greenhouse,)))
        s.skill = [forecast_skill(conn, greenhouse, h) for h in horizons]
        s.findings = [f"{e} since {time.strftime('%H:%MZ', time.gmtime(st)) if st else 'the start'}"
                      for e, st in q("SELECT effect, start FROM findings ORDER BY first_seen")]
    finally:
        conn.close()
    s.received = count(cloud_db, "SELECT count(*) FROM messages")
    return s

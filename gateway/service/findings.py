"""A diagnosis run's findings merged into the store under a stable identity: a finding of the
same effect in the same greenhouse whose start is within ``MATCH_S`` of a known one *is* that
one (a daily re-run moves the estimated start a little); it changes (a new revision, published
again) only when its start moved by more than ``MOVE_S`` or its amplitude by more than
``CHANGE_REL``."""

from __future__ import annotations

import json
import sqlite3
import time
from typing import Any

import numpy as np

from gateway.store.db import transaction

MATCH_S = 12 * 3600.0
MOVE_S = 3600.0
CHANGE_REL = 0.10


def _parse(start: str | None) -> float | None:
    if not start:
        return None
    return float(np.datetime64(start.rstrip("Z"), "s").astype("int64"))


def _amplitude(f: dict[str, Any]) -> float:
    return next((float(v) for k, v in f.get("params", {}).items()
                 if k != "unit" and isinstance(v, int | float)), 0.0)


def store_findings(conn: sqlite3.Connection, greenhouse: str, found: list[dict[str, Any]],
                   now: float) -> list[str]:
    """Merge a diagnosis run's findings into the store (one transaction); returns a line per new
    or changed one."""
    with transaction(conn):
        return merge_findings(conn, greenhouse, found, now)


def merge_findings(conn: sqlite3.Connection, greenhouse: str, found: list[dict[str, Any]],
                   now: float) -> list[str]:
    """:func:`store_findings` within the caller's transaction."""
    notes = []
    known = conn.execute("SELECT id, effect, start, revision, detail FROM findings "
                         "WHERE greenhouse=?", (greenhouse,)).fetchall()
    for f in found:
        effect, start = f["effect"], _parse(f.get("start"))
        same = [k for k in known if k[1] == effect and (
            (k[2] is None and start is None) or
            (k[2] is not None and start is not None and abs(k[2] - start) <= MATCH_S))]
        detail = json.dumps(f)
        if not same:
            stamp = time.strftime("%Y%m%dT%H%MZ", time.gmtime(start)) if start is not None else "before"
            fid = f"{greenhouse}:{effect}-{stamp}"
            conn.execute("INSERT OR IGNORE INTO findings (id, greenhouse, effect, start, "
                         "first_seen, last_seen, revision, detail) VALUES (?, ?, ?, ?, ?, ?, 1, ?)",
                         (fid, greenhouse, effect, start, now, now, detail))
            known.append((fid, effect, start, 1, detail))
            notes.append(f"greenhouse {greenhouse}: new finding {effect} ({f.get('summary', '')})")
            continue
        fid, _, old_start, rev, old = same[0]
        old_amp, amp = _amplitude(json.loads(old)), _amplitude(f)
        moved = (start is not None and old_start is not None and abs(start - old_start) > MOVE_S)
        changed = moved or abs(amp - old_amp) > CHANGE_REL * max(abs(old_amp), 1e-12)
        if changed:
            conn.execute("UPDATE findings SET revision=?, start=?, last_seen=?, detail=? "
                         "WHERE id=?", (rev + 1, start, now, detail, fid))
            notes.append(f"greenhouse {greenhouse}: finding {fid} changed (revision {rev + 1})")
        else:
            conn.execute("UPDATE findings SET last_seen=? WHERE id=?", (now, fid))
    return notes

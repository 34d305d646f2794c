"""Storage bench: what one greenhouse costs the live gateway's SQLite store, per table: rows a
minute, bytes a row (on disk, its indexes included), bytes a day and a year, the size kept under
the default retention, and the estimator snapshot's size (the figures of docs/gateway.md's config
table and of its section "Every minute, per greenhouse").

    python tests/bench/storage.py [--hours 48] [--scale 600]   # writes bench/results/storage.json

Filled by the real thing: ``python -m gateway run`` as a subprocess (tests/gateway_harness.py) on
a scaled clock, one greenhouse per run (each model the kit can feed), a firmware-like kit sending
the reference simulator's trace over UDP; Zenoh on with nobody subscribed, so every message the
producers make stays in the outbox. Measured with SQLite's ``dbstat`` (pages of each table and its
indexes) on a read-only connection while the gateway runs: rows a minute over a window from
``--hours`` − 24 h to ``--hours`` of stepped minutes (a day and a night, after the first day, when
the snapshot's day buffers are full), bytes a row over the whole table at the window's end. The
snapshot is rewritten once ``[estimator] snapshot_every_min`` minutes have been stepped since the
last (the default, 15: ~96 times a day live); its daily write volume is derived from its size
(× 1440 / snapshot_every_min), as a scaled clock batches several minutes at once. What the
estimator writes a day, live (one batch a minute), is measured by tests/bench/snapshot_writes.py.
"""

from __future__ import annotations

import argparse
import json
import math
import sqlite3
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
from _common import write_result  # noqa: E402

from gateway.store.retention import Policy  # noqa: E402
from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, write_config  # noqa: E402
from training.kitsim import KitClock  # noqa: E402

MODELS = ("prototype+vent_control", "prototype")  # almeria needs t_soil: a kit cannot feed it
WINDOW_H = 24.0  # a whole day and night
GROWING = ("samples", "minute", "estimates", "outbox")  # the rest is a row or a few per name


def kept_days() -> dict[str, float]:
    """How long each growing table is kept with the shipped defaults (docs/gateway.md): samples
    ``retention_days``, minutes 10 years (the policy's), estimates ``estimates_days``, sent
    messages ``history_days``; read from the settings dataclass, not copied."""
    from gateway.service.settings import GatewayConfig

    fields = GatewayConfig.__dataclass_fields__
    return {"samples": float(fields["retention_days"].default),
            "minute": Policy().minute_days,
            "estimates": float(fields["estimates_days"].default),
            "outbox": float(fields["history_days"].default)}


class CappedKit(PyKit):
    """A PyKit that sends records 0 … ``last`` − 1 and then nothing new."""

    def __init__(self, *a: Any, last: int, **k: Any) -> None:
        super().__init__(*a, **k)
        self.last = last

    def t(self, seq: int) -> float:
        return math.inf if seq >= self.last else super().t(seq)


def parts(state: Any, path: str = "", depth: int = 3) -> dict[str, int]:
    """Bytes of the snapshot's JSON by part: each key down to ``depth`` levels whose JSON is 2 KB
    or more (what makes the row large)."""
    out = {}
    for key, value in state.items() if isinstance(state, dict) else ():
        name = f"{path}.{key}" if path else str(key)
        size = len(json.dumps(value, separators=(",", ":")))
        if size >= 2000:
            out[name] = size
            if depth > 1:
                out |= parts(value, name, depth - 1)
    return out


def tables(db: Path) -> dict[str, Any]:
    """Rows and on-disk bytes (its pages and its indexes' pages) of every table; the stepped
    minute and the snapshot's size; the file's page and free-page counts."""
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, isolation_level=None)
    try:
        conn.execute("BEGIN")  # one read transaction: every figure of the same commit
        owner = dict(conn.execute("SELECT name, tbl_name FROM sqlite_master WHERE type IN "
                                  "('table', 'index')"))
        out: dict[str, Any] = {}
        for name, size in conn.execute("SELECT name, SUM(pgsize) FROM dbstat GROUP BY name"):
            table = owner.get(name, name)
            if table.startswith("sqlite_"):
                continue
            out.setdefault(table, {"rows": 0, "bytes": 0})["bytes"] += size
        for table in out:
            out[table]["rows"] = conn.execute(f'SELECT count(*) FROM "{table}"').fetchone()[0]
        row = conn.execute("SELECT minute, state FROM estimator_state").fetchone()
        page = conn.execute("PRAGMA page_size").fetchone()[0]
        return {"tables": out, "stepped": row[0] if row else None,
                "snapshot_bytes": len(row[1].encode()) if row else 0,
                "snapshot_parts": parts(json.loads(row[1])) if row else {}, "page_size": page,
                "pages": conn.execute("PRAGMA page_count").fetchone()[0],
                "free_pages": conn.execute("PRAGMA freelist_count").fetchone()[0]}
    finally:
        conn.close()


def _drive(gw: GatewayProcess, kit: PyKit, db: Path, minute: int, timeout: float) -> dict[str, Any]:
    """Feed the kit until the estimator has stepped ``minute``; the store's figures then."""
    target, deadline, look = EPOCH + 60 * minute, time.monotonic() + timeout, 0.0
    while True:
        kit.pump(gw.udp)
        if kit.next >= minute and time.monotonic() > look:
            look = time.monotonic() + 0.5  # a cheap look twice a second; dbstat once, at the end
            if _stepped(db) >= target:
                return tables(db)
        if time.monotonic() > deadline or gw.proc is None or gw.proc.poll() is not None:
            raise RuntimeError(f"minute {minute} not stepped in {timeout:.0f} s:\n{gw.log_tail()}")


def _stepped(db: Path) -> float:
    """The last minute the estimator stepped [unix s] (0 before its first)."""
    if not db.exists():
        return 0.0
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        row = conn.execute("SELECT max(minute) FROM estimator_state").fetchone()
    except sqlite3.OperationalError:  # the schema is not made yet
        return 0.0
    finally:
        conn.close()
    return float(row[0] or 0)


def one_greenhouse(folder: Path, model: str, hours: float, scale: float) -> dict[str, Any]:
    """Run the gateway with one greenhouse of ``model``; the store at the window's two ends."""
    clock = KitClock(scale, EPOCH)
    gh = (f'[[greenhouse]]\nname = "north"\ngreenhouse = "biskra-prototype"\nmodel = "{model}"\n'
          "inside = 7\n")
    cfg = write_config(folder, anchor=clock.anchor, scale=scale, status_every_s=300,
                       greenhouses=gh)
    end = int(hours * 60)
    start = end - int(WINDOW_H * 60)
    kit = CappedKit(7, sim_trace(days=(hours + 6) / 24 + 0.05), clock.now, last=end + 30)
    gw = GatewayProcess(cfg)
    gw.start()
    try:
        budget = 20 * 60 * hours / scale * 60 + 600  # 20× slower than the clock, at worst
        first = _drive(gw, kit, folder / "gw.db", start, budget)
        last = _drive(gw, kit, folder / "gw.db", end, budget)
    finally:
        code = gw.stop()
        kit.close()
    if code != 0:
        raise RuntimeError(f"gateway exited {code}:\n{gw.log_tail()}")
    return {"first": first, "last": last, "wal_bytes": _size(folder / "gw.db-wal"),
            "file_bytes": _size(folder / "gw.db")}


def _size(path: Path) -> int:
    return path.stat().st_size if path.exists() else 0


def _snapshot_every_min() -> int:
    """The default minutes between two saves of the snapshot (read, not copied)."""
    from gateway.service.settings import EstimatorSettings

    return EstimatorSettings.snapshot_every_min


def summarise(run: dict[str, Any]) -> dict[str, Any]:
    """Per growing table: rows a minute over the window, bytes a row at its end, bytes a day,
    MB a year, MB kept with the default retention; totals; the fixed tables; the snapshot."""
    a, b = run["first"], run["last"]
    minutes = (b["stepped"] - a["stepped"]) / 60
    keep = kept_days()
    out: dict[str, Any] = {"window_minutes": minutes, "tables": {}}
    for name in GROWING:
        ta, tb = a["tables"][name], b["tables"][name]
        per_min = (tb["rows"] - ta["rows"]) / minutes
        per_row = tb["bytes"] / tb["rows"]
        per_day = per_min * 1440 * per_row
        out["tables"][name] = {
            "rows_per_minute": round(per_min, 2), "bytes_per_row": round(per_row),
            "kb_per_minute": round(per_min * per_row / 1e3, 2),
            "mb_per_day": round(per_day / 1e6, 2), "mb_per_year": round(per_day * 365 / 1e6),
            "kept_days": keep[name], "mb_kept": round(per_day * keep[name] / 1e6)}
    t = out["tables"]
    out["mb_per_day"] = round(sum(v["mb_per_day"] for v in t.values()), 2)
    out["mb_per_year"] = round(sum(v["mb_per_year"] for v in t.values()))
    out["mb_kept_with_defaults"] = round(sum(v["mb_kept"] for v in t.values()))
    out["fixed_kb"] = {k: round(v["bytes"] / 1e3) for k, v in b["tables"].items() if k not in GROWING}
    snap = b["snapshot_bytes"]
    saves = 1440 / _snapshot_every_min()  # a day, live
    out["snapshot"] = {"bytes": snap, "parts_bytes": b["snapshot_parts"],
                       "saves_per_day": saves,
                       "mb_written_per_day": round(snap * saves / 1e6, 1),
                       "gb_written_per_year": round(snap * saves * 365 / 1e9, 1)}
    out["file"] = {"mb": round(run["file_bytes"] / 1e6, 2), "wal_mb": round(run["wal_bytes"] / 1e6, 2),
                   "free_mb": round(b["free_pages"] * b["page_size"] / 1e6, 2)}
    return out


def run(hours: float = 48.0, scale: float = 600.0) -> dict[str, Any]:
    if hours < 24 + WINDOW_H:
        raise ValueError(f"--hours {hours}: at least {24 + WINDOW_H:g} (a day, then the window)")
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="serra-bench-storage-") as tmp:
        for model in MODELS:
            folder = Path(tmp) / model.replace("+", "-")
            folder.mkdir()
            t0 = time.perf_counter()
            results[model] = summarise(one_greenhouse(folder, model, hours, scale))
            results[model]["wall_s"] = round(time.perf_counter() - t0)
    return {"hours": hours, "scale": scale, "window_hours": WINDOW_H, "greenhouse": "biskra-prototype",
            "trace": "reference simulator, prototype box, Bleiswijk weather, from 2009-11-01 06:00",
            "per_greenhouse": results,
            "summary": {m: {"mb_per_day": r["mb_per_day"], "mb_per_year": r["mb_per_year"],
                            "mb_kept_with_defaults": r["mb_kept_with_defaults"],
                            "snapshot_kb": round(r["snapshot"]["bytes"] / 1e3)}
                        for m, r in results.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python tests/bench/storage.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--hours", type=float, default=48.0,
                        help="simulated hours per run (default 48: a day, then the 24 h window)")
    parser.add_argument("--scale", type=float, default=600.0,
                        help="gateway clock speed-up (default 600)")
    args = parser.parse_args(argv)
    path = write_result("storage", run(args.hours, args.scale))
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

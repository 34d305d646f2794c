"""Estimates-layout bench: the WAL pages a minute the estimate rows cost and the read cost of
every query of the ``estimates`` table, side by side for three layouts in one run.

    python tests/bench/estimates_layout.py [--greenhouses 2] [--days 200] [--rounds 5]
    # writes bench/results/estimates_layout.json (the stores are built under out/)

- ``A``: store version 3: indexes ``estimates_t`` (t) and ``estimates_gh`` (greenhouse, name, t).
- ``B``: one index ``estimates_tgn`` (t, greenhouse, name), and the table ``estimates_latest``
  (each name's newest row), which the "latest of a name" queries read.
- ``C``: as B, the index covering the value: (t, greenhouse, name, value).

Each store holds ``--greenhouses`` × ``--days`` days × 16 rows a minute (the
``prototype+vent_control`` vocabulary without a vsensor), inserted minute by minute, the
indexes built after. Writes: with the checkpoints held off, 60 more minutes are appended (one
transaction a greenhouse-minute, WAL, ``synchronous=FULL``) and the WAL's frames counted by the
b-tree their page belongs to (``snapshot_writes._pages_by_btree``). Reads: each query as the
gateway (or a tool) runs it, in A's form and B's (C's as B's), its plan (EXPLAIN QUERY PLAN), its rows
compared, its time per call in interleaved rounds (the median; each timing repeats the call for
at least 20 ms).
"""

from __future__ import annotations

import argparse
import sqlite3
import statistics
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))  # before HERE: tests/bench/gateway.py is not the package

from _common import write_result  # noqa: E402
from snapshot_writes import _pages_by_btree  # noqa: E402

DAY = 86400.0
T0 = 1.7e9 // 60 * 60
NAMES = ([("measured", "t_in", "degC")]
         + [("online", n, "1") for n in ("c_solar", "c_cnv_cnd", "c_loss", "c_thermal", "c_vc",
                                         "t_vc", "t_in_next")]
         + [("forecast", f"t_in+{h}min", "degC") for h in (15, 30, 60)]
         + [("flux", n, "W m-2") for n in ("q_solar", "q_cnv_cnd", "q_loss", "q_vc", "q_heat")])
LATEST = [
    "CREATE TABLE estimates_latest (greenhouse TEXT NOT NULL, name TEXT NOT NULL, source TEXT NOT "
    "NULL, t REAL NOT NULL, value REAL, unit TEXT NOT NULL, info TEXT NOT NULL, PRIMARY KEY "
    "(greenhouse, name, source)) WITHOUT ROWID",
    # SQLite's bare columns beside max(t) come from the row holding the max
    "INSERT INTO estimates_latest SELECT greenhouse, name, source, max(t), value, unit, info "
    "FROM estimates GROUP BY greenhouse, name, source",
    # every row inserted keeps it, whatever writes it (an older row leaves it)
    "CREATE TRIGGER estimates_latest_upsert AFTER INSERT ON estimates BEGIN "
    "INSERT INTO estimates_latest (greenhouse, name, source, t, value, unit, info) VALUES "
    "(NEW.greenhouse, NEW.name, NEW.source, NEW.t, NEW.value, NEW.unit, NEW.info) "
    "ON CONFLICT (greenhouse, name, source) DO UPDATE SET t = excluded.t, value = excluded.value, "
    "unit = excluded.unit, info = excluded.info WHERE excluded.t >= estimates_latest.t; END"]
INDEXES = {
    "A": ["CREATE INDEX estimates_t ON estimates(t)",
          "CREATE INDEX estimates_gh ON estimates(greenhouse, name, t)"],
    "B": ["CREATE INDEX estimates_tgn ON estimates(t, greenhouse, name)", *LATEST],
    "C": ["CREATE INDEX estimates_tgn ON estimates(t, greenhouse, name, value)", *LATEST],
}


def _rows(ghs: list[str], minute: int) -> list[tuple]:
    t = T0 + 60.0 * minute
    return [(t, src, n, 20.0 + (minute % 997) / 100 + i, unit,
             "clear-sky-trend" if src == "forecast" else "", gh)
            for gh in ghs for i, (src, n, unit) in enumerate(NAMES)]


INSERT = ("INSERT INTO estimates (t, source, name, value, unit, info, greenhouse) "
          "VALUES (?, ?, ?, ?, ?, ?, ?)")


def build(path: Path, layout: str, ghs: list[str], minutes: int) -> None:
    for p in (path, Path(f"{path}-wal"), Path(f"{path}-shm")):
        p.unlink(missing_ok=True)
    c = sqlite3.connect(path, isolation_level=None)
    c.execute("PRAGMA journal_mode=OFF")
    c.execute("PRAGMA synchronous=OFF")
    c.execute("PRAGMA cache_size=-400000")
    c.execute("CREATE TABLE estimates (id INTEGER PRIMARY KEY, t REAL NOT NULL, source TEXT NOT "
              "NULL, name TEXT NOT NULL, value REAL, unit TEXT NOT NULL DEFAULT '', info TEXT NOT "
              "NULL DEFAULT '', greenhouse TEXT NOT NULL DEFAULT '')")
    c.execute("BEGIN")
    for k in range(minutes):
        c.executemany(INSERT, _rows(ghs, k))
    c.execute("COMMIT")
    for stmt in INDEXES[layout]:
        c.execute(stmt)
    # no ANALYZE: the gateway never runs it, so its planner has no sqlite_stat1 (with it, B's
    # day series became a skip-scan of every minute: 0.4 s)
    c.close()


def append_pages(path: Path, ghs: list[str], start: int, n: int) -> dict[str, float]:
    """WAL pages a greenhouse-minute, by b-tree, for ``n`` minutes appended as the gateway does."""
    c = sqlite3.connect(path, isolation_level=None)
    c.execute("PRAGMA journal_mode=WAL")
    c.execute("PRAGMA synchronous=FULL")

    def work() -> None:
        for k in range(start, start + n):
            for gh in ghs:
                rows = _rows([gh], k)
                c.execute("BEGIN IMMEDIATE")
                c.executemany(INSERT, rows)  # B, C: the trigger keeps estimates_latest
                c.execute("COMMIT")

    pages = _pages_by_btree(c, Path(f"{path}-wal"), work)
    c.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    c.close()
    return {k: round(v / (n * len(ghs)), 2) for k, v in pages.items()}


def queries(end: float, gh: str, top_id: int) -> list[tuple[str, bool, str, str, tuple]]:
    """(what, in the rule, A's SQL, B's SQL, parameters): the gateway's queries as in the code
    (status screen ``gateway/status/store_source.py``, producers, retention), then the tools'."""
    same = "{}"
    day = end - DAY
    return [
        ("status: newest t_in_next minute", True,
         "SELECT max(t) FROM estimates WHERE greenhouse=? AND name='t_in_next'",
         "SELECT max(t) FROM estimates_latest WHERE greenhouse=? AND name='t_in_next'", (gh,)),
        ("status: rows of that minute", True,
         "SELECT source, name, value, info FROM estimates WHERE greenhouse=? AND t=?", same,
         (gh, end)),
        ("status: prediction made a minute before", True,
         "SELECT value FROM estimates WHERE greenhouse=? AND name='t_in_next' AND t=?", same,
         (gh, end - 60)),
        ("status: measured T_in, a day", True,
         "SELECT t, value FROM estimates WHERE greenhouse=? AND name='t_in' AND t>?", same,
         (gh, day)),
        ("status: 60-min forecast, a day", True,
         "SELECT t, value FROM estimates WHERE greenhouse=? AND name=? AND t>?", same,
         (gh, "t_in+60min", day - 3600)),
        ("status: a parameter's newest value", True,
         "SELECT value, unit FROM estimates WHERE greenhouse=? AND name=? AND source='online' "
         "ORDER BY t DESC LIMIT 1",
         "SELECT value, unit FROM estimates_latest WHERE greenhouse=? AND name=? "
         "AND source='online'", (gh, "c_loss")),
        ("status: parameter names at a minute (no greenhouse file)", True,
         "SELECT name FROM estimates WHERE greenhouse=? AND t=? AND source='online' "
         "AND name<>'t_in_next' ORDER BY id", same, (gh, end)),
        ("status: newest ventilation_flow (none stored)", True,
         "SELECT t, value, info FROM estimates WHERE greenhouse=? AND name=? "
         "ORDER BY t DESC LIMIT 1",
         "SELECT t, value, info FROM estimates_latest WHERE greenhouse=? AND name=? "
         "ORDER BY t DESC LIMIT 1", (gh, "ventilation_flow")),
        ("status: forecast skill, 15 min, a day", True,
         "SELECT f.value, m0.value, m1.value FROM estimates f "
         "JOIN estimates m0 ON m0.greenhouse=f.greenhouse AND m0.name='t_in' AND m0.t=f.t "
         "JOIN estimates m1 ON m1.greenhouse=f.greenhouse AND m1.name='t_in' AND m1.t=f.t+? "
         "WHERE f.greenhouse=? AND f.name=? AND f.t>=? AND f.value IS NOT NULL "
         "AND m0.value IS NOT NULL AND m1.value IS NOT NULL", same,
         (900.0, gh, "t_in+15min", day)),
        ("producer: rows after the cursor", True,
         "SELECT id, greenhouse, t, source, name, value, unit, info FROM estimates "
         "WHERE id>? ORDER BY id LIMIT ?", same, (top_id - 32, 400)),
        ("retention: rows older than the cut (none)", True,
         "SELECT rowid FROM estimates WHERE t < ? LIMIT 5000", same, (T0 - 1,)),
        ("retention: newest rows older than the cut (none)", True,
         "SELECT 1 WHERE ? < 0", "SELECT t FROM estimates_latest WHERE t < ?", (T0 - 1,)),
        ("no caller: live.latest_estimates", False,
         "SELECT e.t, e.source, e.name, e.value, e.unit, e.info FROM estimates e JOIN "
         "(SELECT name, max(t) AS t FROM estimates WHERE greenhouse=? GROUP BY name) m "
         "ON e.name = m.name AND e.t = m.t WHERE e.greenhouse=?",
         "SELECT t, source, name, value, unit, info FROM estimates_latest WHERE greenhouse=? "
         "AND ?=greenhouse", (gh, gh)),
        ("no caller: live.estimate_series, a day", False,
         "SELECT t, value FROM estimates WHERE greenhouse=? AND name=? AND t>=? ORDER BY t",
         same, (gh, "t_in_next", day)),
        ("test only: Store.estimates, a day", False,
         "SELECT t, source, value FROM estimates WHERE name=? AND t>=? ORDER BY t", same,
         ("c_loss", day)),
        ("training summary: t_in_next count", False,
         "SELECT count(*) FROM estimates WHERE greenhouse=? AND name='t_in_next'", same, (gh,)),
        ("training summary: forecast names", False,
         "SELECT DISTINCT name FROM estimates WHERE greenhouse=? AND source='forecast'", same,
         (gh,)),
        ("training cli: t_in_next count", False,
         "SELECT count(*) FROM estimates WHERE name=?", same, ("t_in_next",)),
    ]


def _time(c: sqlite3.Connection, sql: str, args: tuple) -> float:
    n, t0 = 0, time.perf_counter()
    while True:
        c.execute(sql, args).fetchall()
        n += 1
        dt = time.perf_counter() - t0
        if dt >= 0.02:
            return dt / n


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python tests/bench/estimates_layout.py",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--greenhouses", type=int, default=2)
    p.add_argument("--days", type=float, default=200.0)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--folder", type=Path, default=ROOT / "out" / "estimates_layout")
    args = p.parse_args(argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    ghs = [f"gh{i}" for i in range(args.greenhouses)]
    minutes = int(args.days * 1440)
    paths = {k: args.folder / f"{k}.db" for k in INDEXES}
    out: dict[str, Any] = {"greenhouses": len(ghs), "days": args.days,
                           "rows": minutes * len(ghs) * len(NAMES), "rounds": args.rounds}
    build_s, pages = {}, {}
    for k, path in paths.items():
        t0 = time.perf_counter()
        build(path, k, ghs, minutes)
        build_s[k] = round(time.perf_counter() - t0)
        pages[k] = append_pages(path, ghs, minutes, 60)
        out["size_mb"] = {**out.get("size_mb", {}), k: round(path.stat().st_size / 1e6)}
    out["build_s"], out["pages_per_greenhouse_minute"] = build_s, pages
    end = T0 + 60.0 * (minutes + 59)
    conns = {k: sqlite3.connect(f"file:{p}?mode=ro", uri=True) for k, p in paths.items()}
    top = conns["A"].execute("SELECT max(id) FROM estimates").fetchone()[0]
    qs = queries(end, ghs[0], top)
    times: dict[str, dict[str, list[float]]] = {q[0]: {k: [] for k in paths} for q in qs}
    report, sql_of = [], {}
    for what, rule, sql_a, sql_b, a in qs:
        sqls = {k: sql_a if k == "A" or sql_b == "{}" else sql_b for k in paths}
        sql_of[what] = sqls
        res = {k: sorted(map(repr, conns[k].execute(sqls[k], a).fetchall())) for k in sqls}
        plans = {k: [r[3] for r in conns[k].execute("EXPLAIN QUERY PLAN " + sqls[k], a)]
                 for k in sqls}
        report.append({"what": what, "in_rule": rule, "sql": sqls, "plan": plans,
                       "rows": len(res["A"]),
                       "same_rows": all(res[k] == res["A"] for k in res)})
    for i in range(args.rounds):
        order = list(paths) if i % 2 == 0 else list(paths)[::-1]
        for what, _rule, _a, _b, a in qs:
            for k in order:
                times[what][k].append(_time(conns[k], sql_of[what][k], a))
    for r in report:
        med = {k: statistics.median(v) for k, v in times[r["what"]].items()}
        r["ms"] = {k: round(1e3 * v, 4) for k, v in med.items()}
        r["ratio_to_a"] = {k: round(med[k] / med["A"], 2) for k in med if k != "A"}
    for c in conns.values():
        c.close()
    out["queries"] = report
    print(write_result("estimates_layout", out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

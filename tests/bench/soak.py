"""Soak bench: does the live gateway stay flat over weeks? Its memory, file descriptors, threads,
CPU, store and outbox sampled every simulated hour over many simulated days, per day, with the
slope of what grows.

    python tests/bench/soak.py [--days 12] [--scale 1440] [--greenhouses 1]   # bench/results/soak.json

The real thing: ``python -m gateway run`` as a subprocess (tests/gateway_harness.py) on a scaled
clock (docs/gateway.md, "Test/demo clock"), with the gateway's defaults (retention, estimator
snapshots, status every 300 s, the daily diagnosis in its subprocess), one firmware-like kit
sending the reference simulator's trace over UDP, and a local Zenoh peer subscribed to
``serra/**`` so the publisher drains the outbox (``--no-subscriber``: nobody listens, the outbox
holds every message). ``--greenhouses N`` puts N greenhouses on the same kit.

Every ``--sample-min`` simulated minutes, from /proc: the gateway's VmRSS, open file descriptors,
threads and CPU seconds (its own, and its waited-for children's: the diagnosis runs), and the
same of any live child (a running diagnosis); the store's file and WAL sizes, the outbox's
unsent messages and every small table's rows (meta, findings, status, ...) on a read-only
connection; the minute the estimator has stepped (how far it lags the clock). Per simulated day:
RSS (first, last, max), fds and threads (min and max: a diagnosis run adds some for its
seconds), store MB, CPU seconds. The summary: RSS slope [MB/day] by least squares over the
second half of the run (after the warm-up: the estimator's day buffers, the first diagnosis),
RSS after day 1 beside the last day's, fds and threads of day 1 beside the last day's (their
minima), store growth [MB/day] over the second half, CPU seconds per simulated day, and
``growing``: what rose every day of the second half or by more than a tolerance (a leak
unless it is data kept by design: samples, minutes, estimates, sent messages).
"""

from __future__ import annotations

import argparse
import os
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

from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, write_config  # noqa: E402
from training.kitsim import KitClock  # noqa: E402

DAY = 86400.0
DIAGNOSIS = "enabled = true"  # the [diagnosis] table's body: on, with its defaults
KEPT_BY_DESIGN = ("samples", "minute", "estimates", "outbox")  # grow until their retention


def proc(pid: int) -> dict[str, float]:
    """VmRSS [MB], open fds, threads, CPU seconds (own; waited-for children's) of ``pid``."""
    status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines())
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return {"rss_mb": int(status["VmRSS"].split()[0]) / 1024,
            "fds": len(os.listdir(f"/proc/{pid}/fd")), "threads": int(status["Threads"]),
            "cpu_s": (int(f[11]) + int(f[12])) / tick,
            "children_cpu_s": (int(f[13]) + int(f[14])) / tick}


def children(pid: int) -> list[int]:
    """Live descendants of ``pid`` (Linux's /proc/<pid>/task/<tid>/children)."""
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:  # the thread ended meanwhile
            pass
    return out + [d for c in out for d in _safe(children, c)]


def _safe(fn: Any, pid: int) -> Any:
    try:
        return fn(pid)
    except (OSError, ValueError, KeyError):  # the child ended between the listing and the read
        return [] if fn is children else None


def store(db: Path) -> dict[str, Any]:
    """File and WAL bytes; unsent messages; rows of every table but the big growing ones, and the
    bytes of ``meta``'s values (the estimator's journal lives there)."""
    out: dict[str, Any] = {"db_bytes": _size(db), "wal_bytes": _size(db.with_name(db.name + "-wal"))}
    if not db.exists():
        return out
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, isolation_level=None)
    try:
        conn.execute("BEGIN")
        names = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table' "
                                            "AND name NOT LIKE 'sqlite_%'")]
        out["rows"] = {n: conn.execute(f'SELECT count(*) FROM "{n}"').fetchone()[0]
                       for n in names if n not in ("samples", "minute", "estimates")}
        out["unsent"] = conn.execute("SELECT count(*) FROM outbox WHERE sent IS NULL").fetchone()[0]
        out["meta_bytes"] = conn.execute("SELECT coalesce(sum(length(value)), 0) FROM meta").fetchone()[0]
        row = conn.execute("SELECT min(minute) FROM estimator_state").fetchone()
        out["stepped"] = row[0]
    except sqlite3.OperationalError:  # the schema is not made yet
        pass
    finally:
        conn.close()
    return out


def _size(path: Path) -> int:
    return path.stat().st_size if path.exists() else 0


def sample(gw: GatewayProcess, db: Path, sim_t: float) -> dict[str, Any]:
    assert gw.proc is not None
    pid = gw.proc.pid
    s: dict[str, Any] = {"sim_day": (sim_t - EPOCH) / DAY, "wall": time.monotonic(), **proc(pid)}
    kids = [k for k in (_safe(proc, c) for c in children(pid)) if k]
    s["child_rss_mb"] = sum(k["rss_mb"] for k in kids)
    s["child_cpu_s"] = sum(k["cpu_s"] for k in kids)
    s["n_children"] = len(kids)
    s.update(store(db))
    return s


def slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of ys on xs."""
    n = len(xs)
    if n < 2:
        return 0.0
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx if sxx else 0.0


def per_day(samples: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each simulated day's figures from its samples (and the last sample of the day before)."""
    days: dict[int, list[dict[str, Any]]] = {}
    for s in samples:
        days.setdefault(int(s["sim_day"]), []).append(s)
    out, prev = [], samples[0]
    for d in sorted(days):
        ss, last = days[d], days[d][-1]
        cpu = (last["cpu_s"] + last["children_cpu_s"] + last["child_cpu_s"]
               - prev["cpu_s"] - prev["children_cpu_s"] - prev["child_cpu_s"])
        span = last["sim_day"] - prev["sim_day"]
        out.append({
            "day": d + 1, "samples": len(ss),
            "rss_mb_first": round(ss[0]["rss_mb"], 1), "rss_mb_last": round(last["rss_mb"], 1),
            "rss_mb_max": round(max(s["rss_mb"] for s in ss), 1),
            "child_rss_mb_max": round(max(s["child_rss_mb"] for s in ss), 1),
            "fds_min": min(s["fds"] for s in ss), "fds_max": max(s["fds"] for s in ss),
            "threads_min": min(s["threads"] for s in ss), "threads_max": max(s["threads"] for s in ss),
            "store_mb": round((last["db_bytes"] + last["wal_bytes"]) / 1e6, 2),
            "wal_mb_max": round(max(s["wal_bytes"] for s in ss) / 1e6, 2),
            "unsent_max": max(s.get("unsent", 0) for s in ss),
            "meta_bytes": last.get("meta_bytes", 0), "rows": last.get("rows", {}),
            "cpu_s_per_day": round(cpu / span, 1) if span > 0 else None,
            "wall_s": round(last["wall"] - prev["wall"], 1),
            "lag_min": round((last["sim_day"] * DAY + EPOCH - (last.get("stepped") or EPOCH)) / 60),
        })
        prev = last
    return out


def growing(days: list[dict[str, Any]]) -> dict[str, Any]:
    """What rose over the second half: a small table's rows or meta's bytes that rose every day
    of it, fds or threads whose daily minimum rose (not a diagnosis run's transient)."""
    half = days[len(days) // 2:]
    out: dict[str, Any] = {}
    if len(half) < 2:
        return out
    for name in half[-1]["rows"]:
        counts = [d["rows"].get(name, 0) for d in half]
        if name not in KEPT_BY_DESIGN and all(b > a for a, b in zip(counts, counts[1:], strict=False)):
            out[f"rows:{name}"] = counts
    meta = [d["meta_bytes"] for d in half]
    if all(b > a for a, b in zip(meta, meta[1:], strict=False)):
        out["meta_bytes"] = meta
    for key in ("fds_min", "threads_min"):
        if days[-1][key] > days[0][key] + (2 if key == "fds_min" else 1):
            out[key] = [d[key] for d in days]
    return out


def window_days(diagnosis: str) -> float:
    """The days each diagnosis run exports (``days`` in ``diagnosis``, else the default)."""
    import tomllib

    from gateway.service.settings import DiagnosisSettings

    return float(tomllib.loads(diagnosis).get("days", DiagnosisSettings.days))


def summarise(samples: list[dict[str, Any]], days: list[dict[str, Any]],
              window: float) -> dict[str, Any]:
    """``window``: the days a diagnosis run exports. Its export's peak grows with the data until
    the window is full (the gateway's heap keeps its high-water mark), so the RSS slope is also
    given from half a day after the first run with a full window."""
    end = samples[-1]["sim_day"]
    full = [s for s in samples if s["sim_day"] >= window + 0.5]
    full_slope = (round(slope([s["sim_day"] for s in full], [s["rss_mb"] for s in full]), 2)
                  if full and end - full[0]["sim_day"] >= 1 else None)
    second = [s for s in samples if s["sim_day"] >= end / 2]
    x = [s["sim_day"] for s in second]
    rss_slope = slope(x, [s["rss_mb"] for s in second])
    store_slope = slope(x, [(s["db_bytes"] + s["wal_bytes"]) / 1e6 for s in second])
    first, last = days[0], days[-1]
    cpu = [d["cpu_s_per_day"] for d in days[len(days) // 2:] if d["cpu_s_per_day"] is not None]
    cpu_day = sum(cpu) / len(cpu) if cpu else None
    return {
        "simulated_days": round(end, 2),
        "rss_slope_mb_per_day_second_half": round(rss_slope, 2),
        "rss_slope_mb_per_day_diagnosis_window_full": full_slope,
        "rss_mb_after_day_1": first["rss_mb_last"], "rss_mb_last_day": last["rss_mb_last"],
        "rss_last_vs_day_1": round(last["rss_mb_last"] / first["rss_mb_last"], 3),
        "rss_mb_max": max(d["rss_mb_max"] for d in days),
        "diagnosis_child_rss_mb_max": max(d["child_rss_mb_max"] for d in days),
        "fds_day_1_min": first["fds_min"], "fds_last_day_min": last["fds_min"],
        "fds_max": max(d["fds_max"] for d in days),
        "threads_day_1_min": first["threads_min"], "threads_last_day_min": last["threads_min"],
        "threads_max": max(d["threads_max"] for d in days),
        "store_mb_per_day_second_half": round(store_slope, 2),
        "store_mb_last": last["store_mb"], "wal_mb_max": max(d["wal_mb_max"] for d in days),
        "unsent_max": max(d["unsent_max"] for d in days), "unsent_last": samples[-1].get("unsent"),
        "cpu_s_per_simulated_day_second_half": round(cpu_day, 1) if cpu_day is not None else None,
        "cpu_pct_of_a_core_at_real_time": round(100 * cpu_day / DAY, 3) if cpu_day else None,
        "estimator_lag_min_at_end": last["lag_min"],
        "growing": growing(days),
    }


def soak(folder: Path, days: float, scale: float, greenhouses: int, sample_min: float,
         subscriber: bool, diagnosis: str) -> dict[str, Any]:
    clock = KitClock(scale, EPOCH)
    ghs = "".join(f'[[greenhouse]]\nname = "{"north" if i == 0 else f"g{i + 1}"}"\n'
                  'greenhouse = "biskra-prototype"\nmodel = "prototype+vent_control"\ninside = 7\n'
                  for i in range(greenhouses))
    cfg = write_config(folder, anchor=clock.anchor, scale=scale, status_every_s=300,
                       greenhouses=ghs, diagnosis=diagnosis)
    trace = sim_trace(days=days + 0.5)
    gw = GatewayProcess(cfg)
    kit = PyKit(7, trace, clock.now)
    sess = sub = None
    received = [0]
    samples: list[dict[str, Any]] = []
    db = folder / "gw.db"
    gw.start()
    try:
        if subscriber:
            import zenoh

            from gateway.publish import zconfig

            sess = zenoh.open(zconfig.build(connect=[gw.zenoh]))
            sub = sess.declare_subscriber("serra/**", lambda _s: received.__setitem__(0, received[0] + 1))
        end, next_t = EPOCH + days * DAY, EPOCH
        while (now := clock.now()) < end:
            kit.pump(gw.udp)
            if now >= next_t:
                if gw.proc is None or gw.proc.poll() is not None:
                    raise RuntimeError(f"gateway exited:\n{gw.log_tail()}")
                samples.append(sample(gw, db, now))
                next_t += sample_min * 60
        samples.append(sample(gw, db, clock.now()))
    finally:
        if sub is not None:
            sub.undeclare()
        if sess is not None:
            sess.close()
        code = gw.stop(timeout=120)
        kit.close()
    log = (folder / "gateway.log").read_text()
    return {"samples": samples, "exit": code, "received": received[0],
            "diagnosis_runs": log.count(": diagnosis of "),
            "diagnosis_skipped": log.count(": diagnosis skipped"),
            "log_warnings": [ln for ln in log.splitlines() if " WARNING " in ln or "ERROR" in ln][:20]}


def run(days: float = 12.0, scale: float = 1440.0, greenhouses: int = 1, sample_min: float = 60.0,
        subscriber: bool = True, diagnosis: str = DIAGNOSIS) -> dict[str, Any]:
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="serra-bench-soak-") as tmp:
        r = soak(Path(tmp), days, scale, greenhouses, sample_min, subscriber, diagnosis)
    daily = per_day(r["samples"])
    return {"days": days, "scale": scale, "greenhouses": greenhouses, "sample_min": sample_min,
            "subscriber": subscriber, "diagnosis": diagnosis, "wall_s": round(time.perf_counter() - t0),
            "model": "prototype+vent_control", "greenhouse": "biskra-prototype",
            "trace": "reference simulator, prototype box, Bleiswijk weather, from 2009-11-01 06:00",
            "exit": r["exit"], "messages_received": r["received"],
            "diagnosis_runs": r["diagnosis_runs"], "diagnosis_skipped": r["diagnosis_skipped"],
            "log_warnings": r["log_warnings"],
            "summary": summarise(r["samples"], daily, window_days(diagnosis)),
            "per_day": daily,
            "samples": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in s.items()
                         if k != "rows"} for s in r["samples"]]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python tests/bench/soak.py",
                                     description=__doc__.split("\n\n")[0],
                                     epilog="writes bench/results/soak.json")
    parser.add_argument("--days", type=float, default=12.0,
                        help="simulated days (default 12: the diagnosis's 10-day window fills, "
                             "then two more days; 12 wall minutes at 1440x)")
    parser.add_argument("--scale", type=float, default=1440.0,
                        help="gateway clock speed-up (default 1440: a simulated day in a wall "
                             "minute, ~0.7 of a core for the gateway; lower it on a busy machine)")
    parser.add_argument("--greenhouses", type=int, default=1, help="greenhouses on the one kit (default 1)")
    parser.add_argument("--sample-min", type=float, default=60.0,
                        help="simulated minutes between two samples (default 60)")
    parser.add_argument("--no-subscriber", dest="subscriber", action="store_false",
                        help="no Zenoh peer subscribed: the outbox keeps every message")
    parser.add_argument("--diagnosis", default=DIAGNOSIS, metavar="TOML",
                        help="the [diagnosis] table's body, lines split by ';' (default "
                             f"{DIAGNOSIS!r}: daily over the last 10 days)")
    args = parser.parse_args(argv)
    result = run(args.days, args.scale, args.greenhouses, args.sample_min, args.subscriber,
                 args.diagnosis.replace(";", "\n"))
    print(write_result("soak", result))
    import json

    print(json.dumps(result["summary"], indent=2))
    return 1 if result["exit"] != 0 else 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Fleet bench (issue 13): 10, 30 and 100 simulated gateways (tests/fleet/fleetgw.py: the real
outbox and publisher, client sessions with mutual TLS, 4 processes) → two regional routers → a
cloud router → ``python -m gateway subscribe`` → PostgreSQL, access control on every router.

    python tests/bench/fleet.py            # writes bench/results/fleet.json (make bench runs it)

Per fleet size:
- paced: every gateway makes one kit record (2 messages) every PACE s for ROUNDS rounds;
  latency p50/p99 from the outbox's send time to the subscriber's arrival time (two router
  hops; both clocks are this machine's), beside a bare Zenoh put → callback over the same two
  hops in the same run (the floor); CPU of each part over that window as a fraction of one core
  and per message; RSS of each part.
- burst: every gateway adds BURST records at once; messages/s from the first add to the last
  arrival, rows/s from PostgreSQL's own insert times.
- the PostgreSQL rows checked: lost, duplicated, order per key.
Then, with 100 gateways, the test's scenario (tests/fleet/test_fleet.py): region-1 killed
mid-run, the outage, the restart: failover time, messages held, time to drain, the checks.
Nothing is pinned: the parts share this machine's cores (noted in the JSON).
"""

from __future__ import annotations

import json
import sqlite3
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
import psycopg  # noqa: E402
import zenoh  # noqa: E402
from _common import write_result  # noqa: E402

from gateway.net.zenohcfg import build, client_entries  # noqa: E402
from tests.fleet.fleet import Fleet, FleetPlan, pg_cpu, proc_usage  # noqa: E402
from tests.fleet.kit import wait_until  # noqa: E402
from tests.fleet.pg import PgCluster  # noqa: E402

SIZES = (10, 30, 100)
PROCS = 4
PACE = 0.5  # [s] between records of one gateway (paced phase)
ROUNDS = 20
BURST = 100  # records per gateway in the burst (2 messages each)


def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))] if s else float("nan")


def bare_two_hops(fleet: Fleet, n: int = 300) -> dict[str, float]:
    """Plain Zenoh put → callback, region router → cloud router (same TLS and ACL), in ms."""
    region = fleet.regions[0].endpoints
    got: dict[int, float] = {}
    done = threading.Event()

    def cb(sample: zenoh.Sample) -> None:
        got[int(sample.payload.to_string().split()[0])] = time.perf_counter()
        if len(got) >= n:
            done.set()

    farm = fleet.farms[0]
    with zenoh.open(build(client_entries(fleet.cloud.endpoints, fleet.pki.tls("store")))) as sub_s, \
            zenoh.open(build(client_entries(region, fleet.pki.tls(farm)))) as pub_s:
        sub = sub_s.declare_subscriber(f"serra/{farm}/probe/x", cb)
        pub = pub_s.declare_publisher(f"serra/{farm}/probe/x",
                                      congestion_control=zenoh.CongestionControl.BLOCK)
        wait_until(lambda: pub.matching_status.matching, what="the probe subscriber")
        sent = {}
        for i in range(n):
            sent[i] = time.perf_counter()
            pub.put(f"{i} probe")
            time.sleep(0.005)  # a pace, not a synchronisation
        done.wait(30)
        pub.undeclare()
        sub.undeclare()
    lat = [(got[i] - sent[i]) * 1e3 for i in sent if i in got]
    return {"p50_ms": pct(lat, 0.5), "p99_ms": pct(lat, 0.99), "n": len(lat)}


def usage(fleet: Fleet, pg: PgCluster) -> dict[str, Any]:
    parts = {"cloud": fleet.cloud.proc.pid, "region-1": fleet.regions[0].proc.pid,
             "region-2": fleet.regions[1].proc.pid, "subscriber": fleet.subscriber.proc.pid}
    out: dict[str, Any] = {name: proc_usage(pid) for name, pid in parts.items()}
    out["workers"] = fleet.worker_usage()
    out["postgres_cpu_s"] = pg_cpu(pg)
    out["t"] = time.monotonic()
    return out


def latencies(fleet: Fleet, first: int, last: int) -> list[float]:
    """Outbox send time → subscriber arrival [ms] of the records first..last-1."""
    sent: dict[tuple[str, str], float] = {}
    for farm in fleet.farms:
        with sqlite3.connect(f"file:{fleet.folder / (farm + '.db')}?mode=ro", uri=True) as c:
            for ident, t in c.execute("SELECT idem, sent FROM outbox WHERE sent IS NOT NULL"):
                seq = int(ident.rsplit("/", 1)[1])
                if first <= seq < last:
                    sent[(farm, ident)] = t
    with psycopg.connect(fleet.pg.dsn) as c:
        rows = c.execute(f"SELECT farm, idem, extract(epoch FROM received)::float8 FROM "
                         f"{fleet.plan.schema}.message").fetchall()
    return [(r - sent[(f, i)]) * 1e3 for f, i, r in rows if (f, i) in sent]


def cpu_share(u0: dict[str, Any], u1: dict[str, Any], msgs: int) -> dict[str, Any]:
    wall = u1["t"] - u0["t"]
    out: dict[str, Any] = {"wall_s": wall}
    for name in ("cloud", "region-1", "region-2", "subscriber"):
        d = u1[name]["cpu_s"] - u0[name]["cpu_s"]
        out[name] = {"core": d / wall, "us_per_msg": d / msgs * 1e6}
    gw = sum(b["cpu_s"] - a["cpu_s"] for a, b in zip(u0["workers"], u1["workers"], strict=True))
    n = sum(w["gateways"] for w in u1["workers"])
    out["gateway"] = {"core": gw / wall / n, "us_per_msg": gw / msgs * 1e6}
    pg = u1["postgres_cpu_s"] - u0["postgres_cpu_s"]
    out["postgres"] = {"core": pg / wall, "us_per_msg": pg / msgs * 1e6}
    return out


def memory(u: dict[str, Any]) -> dict[str, Any]:
    workers = u["workers"]
    n = sum(w["gateways"] for w in workers)
    return {**{name: u[name]["rss_mb"] for name in ("cloud", "region-1", "region-2", "subscriber")},
            "worker_process": sum(w["rss_mb"] for w in workers) / len(workers),
            "worker_base": sum(w["base"]["rss_mb"] for w in workers) / len(workers),
            "per_gateway": sum(w["rss_mb"] - w["base"]["rss_mb"] for w in workers) / n}


def size_run(n: int, pg: PgCluster, folder: Path) -> dict[str, Any]:
    plan = FleetPlan(gateways=n, procs=PROCS, single_every=0, schema=f"bench_{n}")
    t_start = time.monotonic()
    with Fleet(folder, pg, plan) as fleet:
        fleet.wait_open()
        started_s = time.monotonic() - t_start
        fleet.produce(0, 1)
        fleet.wait_produced()
        fleet.wait_stored(fleet.expected_count())
        floor = bare_two_hops(fleet)
        u0 = usage(fleet, pg)
        fleet.produce(1, 1 + ROUNDS, interval=PACE)
        fleet.wait_produced()
        fleet.wait_stored(fleet.expected_count())
        u1 = usage(fleet, pg)
        paced_msgs = n * ROUNDS * 2
        lat = latencies(fleet, 1, 1 + ROUNDS)
        t0, wall0 = time.monotonic(), time.time()
        fleet.produce(1 + ROUNDS, 1 + ROUNDS + BURST)
        fleet.wait_produced()
        fleet.wait_stored(fleet.expected_count())
        with psycopg.connect(pg.dsn) as c:
            (last_arrival,) = c.execute(f"SELECT extract(epoch FROM max(received)) FROM "
                                        f"{plan.schema}.message").fetchone()
        burst_msgs = n * BURST * 2
        burst_wall = float(last_arrival) - wall0
        mem = memory(usage(fleet, pg))
        fleet.stop_workers()
        check = fleet.check()
        fleet.subscriber.stop()
        stats = fleet.subscriber_stats()
        with psycopg.connect(pg.dsn, autocommit=True) as c:
            c.execute(f"DROP SCHEMA {plan.schema} CASCADE")
    return {
        "gateways": n, "processes": PROCS, "start_s": started_s,
        "paced": {"messages": paced_msgs, "rate_msgs_s": n * 2 / PACE,
                  "latency_p50_ms": pct(lat, 0.5), "latency_p99_ms": pct(lat, 0.99),
                  "latency_n": len(lat), "bare_two_hops": floor, "cpu": cpu_share(u0, u1, paced_msgs)},
        "burst": {"messages": burst_msgs, "msgs_per_s": burst_msgs / burst_wall,
                  "wall_s": burst_wall, "drain_s": time.monotonic() - t0},
        "store": {"rows": stats.get("stored"), "insert_s": stats.get("store_s"),
                  "rows_per_s": stats["stored"] / stats["store_s"] if stats.get("store_s") else None,
                  "repeats": stats.get("repeats"), "missed": stats.get("missed")},
        "rss_mb": mem,
        "check": {"expected": check.expected, "stored": check.stored, "lost": check.lost,
                  "duplicated": check.duplicated, "out_of_order_keys": len(check.out_of_order)},
    }


def restart_run(pg: PgCluster, folder: Path, n: int = 100, records: int = 6) -> dict[str, Any]:
    """The fleet test's scenario, timed: region-1 killed mid-run, the outage, the restart."""
    plan = FleetPlan(gateways=n, procs=PROCS, single_every=10, schema="bench_restart")
    with Fleet(folder, pg, plan) as fleet:
        fleet.wait_open()
        single = {f for i, f in enumerate(fleet.farms) if i % plan.single_every == 0}
        fleet.produce(0, records, interval=0.1)
        fleet.wait_produced()
        fleet.wait_stored(fleet.expected_count())
        port, r2 = fleet.regions[0].port, fleet.regions[1]
        before = fleet.expected_count()
        fleet.produce(records, 2 * records, interval=0.1)
        fleet.wait_stored(before + (fleet.expected_count() - before) // 10)
        t_kill = time.monotonic()
        fleet.regions[0].kill()
        wait_until(lambda: all(g["routers"] == [r2.zid] for g in fleet.status() if g["farm"] not in single),
                   what="failover", interval=0.1)
        failover_s = time.monotonic() - t_kill
        fleet.wait_produced()
        fleet.produce(2 * records, 3 * records, interval=0.1)
        fleet.wait_produced()
        held = sum(g["pending"] for g in fleet.status() if g["farm"] in single)
        t_back = time.monotonic()
        fleet.regions[0] = fleet.start_region("region-1", port)
        t_up = time.monotonic()
        fleet.wait_stored(fleet.expected_count())
        recovered_s = time.monotonic() - t_back
        fleet.produce(3 * records, 4 * records, interval=0.1)
        fleet.wait_produced()
        fleet.wait_stored(fleet.expected_count())
        fleet.stop_workers()
        check = fleet.check()
        fleet.subscriber.stop()
        stats = fleet.subscriber_stats()
        with psycopg.connect(pg.dsn, autocommit=True) as c:
            c.execute(f"DROP SCHEMA {plan.schema} CASCADE")
    return {"gateways": n, "single_homed": len(single), "messages": check.expected,
            "failover_s": failover_s, "held_during_outage": held,
            "router_restart_s": t_up - t_back, "restart_to_all_stored_s": recovered_s,
            "lost": check.lost, "duplicated": check.duplicated,
            "unexpected": check.unexpected, "out_of_order_keys": len(check.out_of_order),
            "subscriber": stats}


def table(sizes: list[dict[str, Any]]) -> str:
    """The README's cost table (markdown)."""
    lines = ["| gateways | paced msgs/s | p50 / p99 ms, 2 router hops | bare Zenoh p50 / p99 ms | "
             "CPU per router, % core | CPU per gateway, % core | RSS per router MB | "
             "RSS per gateway MB | burst msgs/s | PostgreSQL rows/s |", "|" + " --- |" * 10]
    routers = ("cloud", "region-1", "region-2")
    for s in sizes:
        cpu, mem, p = s["paced"]["cpu"], s["rss_mb"], s["paced"]
        core = [100 * cpu[r]["core"] for r in routers]
        rss = [mem[r] for r in routers]
        lines.append(
            f"| {s['gateways']} | {p['rate_msgs_s']:.0f} | "
            f"{p['latency_p50_ms']:.1f} / {p['latency_p99_ms']:.1f} | "
            f"{p['bare_two_hops']['p50_ms']:.2f} / {p['bare_two_hops']['p99_ms']:.2f} | "
            f"{min(core):.1f}–{max(core):.1f} | {100 * cpu['gateway']['core']:.2f} | "
            f"{min(rss):.0f}–{max(rss):.0f} | {mem['per_gateway']:.1f} | "
            f"{s['burst']['msgs_per_s']:.0f} | {s['store']['rows_per_s'] or 0:.0f} |")
    return "\n".join(lines)


def run(sizes_wanted: tuple[int, ...] = SIZES, with_restart: bool = True) -> dict[str, Any]:
    restart: dict[str, Any] = {}
    with PgCluster() as pg, tempfile.TemporaryDirectory(prefix="serra-fleet-bench-") as tmp:
        sizes = []
        for n in sizes_wanted:
            folder = Path(tmp) / f"n{n}"
            folder.mkdir()
            print(f"fleet bench: {n} gateways", flush=True)
            sizes.append(size_run(n, pg, folder))
        if with_restart:
            folder = Path(tmp) / "restart"
            folder.mkdir()
            print("fleet bench: region-1 restart with 100 gateways", flush=True)
            restart = restart_run(pg, folder)
    if not sizes:
        return {"summary": {"table": "", "restart": restart}, "restart": restart}
    small, big = sizes[0], sizes[-1]
    growth = {
        "gateways": big["gateways"] / small["gateways"],
        "msgs_per_s": big["burst"]["msgs_per_s"] / small["burst"]["msgs_per_s"],
        "latency_p50": big["paced"]["latency_p50_ms"] / small["paced"]["latency_p50_ms"],
        "latency_p99": big["paced"]["latency_p99_ms"] / small["paced"]["latency_p99_ms"],
        "cloud_router_cpu": big["paced"]["cpu"]["cloud"]["core"] / small["paced"]["cpu"]["cloud"]["core"],
        "cloud_router_us_per_msg": (big["paced"]["cpu"]["cloud"]["us_per_msg"]
                                    / small["paced"]["cpu"]["cloud"]["us_per_msg"]),
        "cloud_router_rss": big["rss_mb"]["cloud"] / small["rss_mb"]["cloud"],
        "gateway_cpu_us_per_msg": (big["paced"]["cpu"]["gateway"]["us_per_msg"]
                                   / small["paced"]["cpu"]["gateway"]["us_per_msg"]),
    }
    summary = {"table": table(sizes), "growth_10_to_100": growth, "restart": restart,
               "all_checks_clean": all(s["check"]["lost"] == 0 and s["check"]["duplicated"] == 0
                                       and s["check"]["out_of_order_keys"] == 0 for s in sizes)}
    return {"summary": summary, "sizes": sizes, "restart": restart,
            "settings": {"pace_s": PACE, "rounds": ROUNDS, "burst_records": BURST, "processes": PROCS}}


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=(
        "without arguments: every size and the restart, written to bench/results/fleet.json; "
        "with sizes: a quick look, printed only"))
    ap.add_argument("sizes", nargs="*", type=int, metavar="N", help="gateways per run")
    ap.add_argument("--restart", action="store_true", help="with sizes: the restart run too")
    a = ap.parse_args()
    args = a.sizes
    result = run(tuple(args) if args else SIZES, not args or a.restart)
    if args:
        print(result["summary"]["table"])
        print(json.dumps({k: v for k, v in result["summary"].items() if k != "table"}, indent=2))
        raise SystemExit(0)
    path = write_result("fleet", result)
    print(f"wrote {path}")
    print(result["summary"]["table"])
    print(json.dumps({k: v for k, v in result["summary"].items() if k != "table"}, indent=2))

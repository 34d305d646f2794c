"""A fleet on loopback for the fleet test and bench: simulated gateways (tests/fleet/fleetgw.py,
several processes) → two regional routers → one cloud router → ``python -m gateway subscribe``
storing into PostgreSQL. Mutual TLS and access control on every link; every part is the real
command or the real code, in its own process.

    with Fleet(tmp, pg, FleetPlan(gateways=100, procs=4)) as fleet:
        fleet.wait_open()
        fleet.produce(0, 5, interval=0.05); fleet.wait_produced()
        fleet.wait_stored(fleet.expected_count())
        check = fleet.check()          # lost, duplicated, out of order, from the PostgreSQL rows

Gateway i connects to [region-1, region-2] (i odd: [region-2, region-1]); every
`single_every`-th gateway lists region-1 only (a farm with one router): when region-1 dies the
others fail over and those hold their messages until it is back.
"""

from __future__ import annotations

import json
import os
import queue
import re
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psycopg

from tests.fleet.fleetgw import SIDES, idem
from tests.fleet.kit import DEADLINE, ROOT, LineProc, Pki, RouterProc, make_pki, wait_until, write_router_toml
from tests.fleet.pg import PgCluster

DATA = ROOT / "training" / "data" / "identifiability_prototype_2days.csv"
REGIONS = ("region-1", "region-2")
ROUTERS = ("cloud", *REGIONS)
TICK = os.sysconf("SC_CLK_TCK")


def farm_name(i: int) -> str:
    return f"farm-{i:03d}"


@dataclass(frozen=True)
class FleetPlan:
    gateways: int = 100
    procs: int = 4
    single_every: int = 10  # every n-th gateway lists region-1 only (0: none)
    cache: int = 256  # samples per key in each advanced publisher
    retry_ms: tuple[int, int] = (100, 500)  # clients' reconnection
    schema: str = "fleet"

    def connect(self, i: int, regions: list[str]) -> list[str]:
        if self.single_every and i % self.single_every == 0:
            return [regions[0]]
        return regions if i % 2 == 0 else regions[::-1]


@dataclass
class FleetCheck:
    """What the PostgreSQL rows say about the run."""

    expected: int
    stored: int
    lost: int
    duplicated: int  # rows beyond one per (farm, idempotency key)
    unexpected: int  # rows nobody sent
    out_of_order: list[str] = field(default_factory=list)  # keys whose records came out of order
    keys: int = 0


def proc_usage(pid: int) -> dict[str, float]:
    """CPU seconds and memory [MB] of a process, from /proc."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    mem = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(("VmRSS:", "VmHWM:")):
                mem[line.split(":")[0]] = int(line.split()[1]) / 1024
    return {"cpu_s": (int(fields[11]) + int(fields[12])) / TICK, "rss_mb": mem.get("VmRSS", 0.0),
            "hwm_mb": mem.get("VmHWM", 0.0)}


def pg_cpu(cluster: PgCluster) -> float:
    """CPU seconds of the PostgreSQL server and its live backends."""
    master = int((cluster.data / "postmaster.pid").read_text().split()[0])
    total = proc_usage(master)["cpu_s"]
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                with open(f"/proc/{pid}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == master:
                        total += proc_usage(int(pid))["cpu_s"]
            except (OSError, ValueError, IndexError):
                continue
    return total


class WorkerProc:
    """One ``python -m tests.fleet.fleetgw`` process: commands in, JSON events out."""

    def __init__(self, spec: Path, log: Path) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.fleet.fleetgw", str(spec)], cwd=ROOT,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=open(log, "a"), text=True)  # noqa: SIM115
        self.events: queue.Queue[dict[str, Any]] = queue.Queue()
        self.ready: dict[str, Any] = {}
        self._kept: list[dict[str, Any]] = []  # events read while waiting for another
        self._n = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.events.put(json.loads(line))
        self.events.put({"event": "exit"})

    def send(self, cmd: dict[str, Any]) -> int:
        self._n += 1
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps({**cmd, "id": self._n}) + "\n")
        self.proc.stdin.flush()
        return self._n

    def wait(self, event: str, ident: int | None = None, timeout: float = DEADLINE) -> dict[str, Any]:
        """The next `event` (with that `ident`); other events are kept for their own waits."""
        def wanted(e: dict[str, Any]) -> bool:
            return e["event"] == event and (ident is None or e.get("id") == ident)

        for e in self._kept:
            if wanted(e):
                self._kept.remove(e)
                return e
        try:
            while True:
                e = self.events.get(timeout=timeout)
                if e["event"] == "exit":
                    raise AssertionError(f"fleet worker exited (code {self.proc.wait()})")
                if wanted(e):
                    return e
                self._kept.append(e)
        except queue.Empty:
            raise AssertionError(f"fleet worker: no {event} in {timeout:g} s") from None

    def close(self, timeout: float = DEADLINE) -> dict[str, Any] | None:
        """Stop (sessions closed, final status) or kill."""
        if self.proc.poll() is not None:
            return None
        try:
            self.send({"cmd": "stop"})
            final = self.wait("stopped", timeout=timeout)
            self.proc.wait(timeout)
            return final
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()


class Fleet:
    def __init__(self, folder: Path, pg: PgCluster, plan: FleetPlan, pki: Pki | None = None) -> None:
        self.folder, self.pg, self.plan = folder, pg, plan
        self.farms = [farm_name(i) for i in range(plan.gateways)]
        self.pki = pki or make_pki(folder / "pki", routers=ROUTERS, gateways=self.farms, clients=("store",))
        self.access = {"gateways": self.farms, "routers": list(ROUTERS),
                       "subscribers": {"store": {"farms": ["*"], "store": True}}}
        self.cloud: RouterProc | None = None
        self.regions: list[RouterProc] = []
        self.subscriber: LineProc | None = None
        self.workers: list[WorkerProc] = []
        self.produced: dict[str, int] = dict.fromkeys(self.farms, 0)  # records per farm so far
        self._pending: list[tuple[WorkerProc, int]] = []

    # -- start and stop -------------------------------------------------------------------------
    def start(self) -> Fleet:
        self.cloud = RouterProc(write_router_toml(self.folder / "cloud.toml", "cloud", self.pki,
                                                  access=self.access)).start()
        for name in REGIONS:
            self.regions.append(self.start_region(name))
        self.subscriber = LineProc([sys.executable, "-m", "gateway", "subscribe", "--config",
                                    str(self._subscriber_toml())], "serra-subscribe ready",
                                   self.folder / "subscribe.log").start()
        per = -(-self.plan.gateways // self.plan.procs)
        endpoints = [r.endpoints[0] for r in self.regions]
        for w in range(self.plan.procs):
            idx = range(w * per, min((w + 1) * per, self.plan.gateways))
            spec = {"ca": str(self.pki.ca.cert), "data": str(DATA), "cache": self.plan.cache,
                    "retry_ms": list(self.plan.retry_ms),
                    "gateways": [{"farm": self.farms[i], "cert": str(self.pki.issued[self.farms[i]].cert),
                                  "key": str(self.pki.issued[self.farms[i]].key), "offset": 37 * i,
                                  "connect": self.plan.connect(i, endpoints),
                                  "db": str(self.folder / f"{self.farms[i]}.db")} for i in idx]}
            path = self.folder / f"worker-{w}.json"
            path.write_text(json.dumps(spec))
            self.workers.append(WorkerProc(path, self.folder / f"worker-{w}.log"))
        for worker in self.workers:
            worker.ready = worker.wait("ready", timeout=DEADLINE * 2)
        return self

    def start_region(self, name: str, port: int | None = None) -> RouterProc:
        assert self.cloud is not None
        listen = [f"tls/127.0.0.1:{port or 0}"]
        return RouterProc(write_router_toml(self.folder / f"{name}.toml", name, self.pki, listen=listen,
                                            connect=self.cloud.endpoints, access=self.access)).start()

    def _subscriber_toml(self) -> Path:
        tls = self.pki.tls("store")
        path = self.folder / "subscriber.toml"
        assert self.cloud is not None
        path.write_text(f"""[subscribe]
mode = "client"
connect = {json.dumps(self.cloud.endpoints)}
access = "cloud.toml"            # the farms the certificate 'store' may read there
dsn = "{self.pg.dsn}"
schema = "{self.plan.schema}"
retry_initial_ms = 100
retry_max_ms = 500

[tls]
ca = "{tls.ca}"
cert = "{tls.cert}"
key = "{tls.key}"
""")
        return path

    def stop_workers(self) -> list[dict[str, Any]]:
        """Stop every worker (publishers drained, sessions closed); their final events."""
        finals = [w.close() for w in self.workers]
        self.workers = []
        return [f for f in finals if f is not None]

    def close(self) -> None:
        for w in self.workers:
            w.close()
        self.workers = []
        for part in (self.subscriber, *self.regions, self.cloud):
            if part is not None and part.proc is not None:
                part.stop()

    def __enter__(self) -> Fleet:
        try:
            return self.start()
        except BaseException:
            self.close()
            raise

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- driving --------------------------------------------------------------------------------
    def produce(self, first: int, last: int, interval: float = 0.0) -> None:
        """Every gateway adds records first..last-1 (returns at once; see wait_produced)."""
        for w in self.workers:
            self._pending.append((w, w.send({"cmd": "produce", "first": first, "last": last,
                                             "interval": interval})))
        for farm in self.farms:
            self.produced[farm] = max(self.produced[farm], last)

    def wait_produced(self, timeout: float = DEADLINE * 2) -> None:
        for w, ident in self._pending:
            w.wait("produced", ident, timeout)
        self._pending = []

    def status(self) -> list[dict[str, Any]]:
        out = []
        for w in self.workers:
            out += w.wait("status", w.send({"cmd": "status"}))["gateways"]
        return out

    def worker_usage(self) -> list[dict[str, Any]]:
        return [{"gateways": w.ready["gateways"], "base": w.ready["base"],
                 **w.wait("status", w.send({"cmd": "status"}))["usage"]} for w in self.workers]

    def wait_open(self, timeout: float = DEADLINE * 2) -> None:
        wait_until(lambda: all(g["open"] for g in self.status()), timeout, "every gateway's session",
                   interval=0.2)

    def expected_count(self) -> int:
        return sum(self.produced.values()) * len(SIDES)

    def stored(self) -> int:
        with psycopg.connect(self.pg.dsn) as c:
            try:
                return int(c.execute(f"SELECT count(*) FROM {self.plan.schema}.message").fetchone()[0])
            except psycopg.errors.UndefinedTable:
                return 0

    def wait_stored(self, n: int, timeout: float = DEADLINE * 3) -> None:
        wait_until(lambda: self.stored() >= n, timeout, f"{n} rows in PostgreSQL", interval=0.2)

    # -- checks ---------------------------------------------------------------------------------
    def rows(self) -> Iterator[tuple[str, str, str]]:
        """(farm, key, idem) in the store's insertion order."""
        with psycopg.connect(self.pg.dsn) as c:
            yield from c.execute(f"SELECT farm, key, idem FROM {self.plan.schema}.message ORDER BY id")

    def check(self) -> FleetCheck:
        expected = {(f, idem(f, side, seq)) for f, n in self.produced.items()
                    for seq in range(n) for side in SIDES}
        seen: set[tuple[str, str]] = set()
        last: dict[str, int] = {}
        dup = unexpected = 0
        bad: set[str] = set()
        for farm, key, ident in self.rows():
            if (farm, ident) in seen:
                dup += 1
            seen.add((farm, ident))
            unexpected += (farm, ident) not in expected
            seq = int(ident.rsplit("/", 1)[1])
            if seq <= last.get(key, -1):
                bad.add(key)
            last[key] = seq
        return FleetCheck(len(expected), len(seen), len(expected - seen), dup, unexpected,
                          sorted(bad), len(last))

    def subscriber_stats(self) -> dict[str, float]:
        """The subscriber's last stats line (printed every 10 s and at exit: ``subscribe: stored
        3, not messages 0, …, storing 0.1 s``), keyed as SubscribeStats' fields (``stored``,
        ``not_messages``; the time spent storing as ``storing``)."""
        assert self.subscriber is not None
        lines = re.findall(r"^subscribe(?: stopped)?: (.*)$", self.subscriber.text(), re.M)
        if not lines:
            return {}
        out = {}
        for item in lines[-1].split(";")[0].split(", "):
            m = re.fullmatch(r"([a-z ]+) ([\d.]+)(?: s)?", item.strip())
            if m:
                name = m.group(1)
                out["store_s" if name == "storing" else name.replace(" ", "_")] = float(m.group(2))
        return out

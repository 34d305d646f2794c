"""A store filled the way the live gateway fills it, in process and fast: kit records of the
reference simulator, the minute aggregation, the real per-greenhouse estimator, the message
producers, a finding from the diagnosis's merge, and the service's status rows. Used by the
status screen's tests (its data layer, widgets and ``--once``)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gateway import protocol as p
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.publish.payloads import Place
from gateway.service.findings import store_findings
from gateway.service.pipeline import GreenhousePipeline
from gateway.service.producers import GreenhouseInfo, Producers
from gateway.store import Store
from gateway.store.aggregate import aggregate
from gateway.store.live import save_greenhouses, set_status
from gateway.store.outbox import Outbox
from tests.gateway_harness import EPOCH, sim_trace

GH = load_greenhouse("biskra-prototype")
MODEL = build_model("prototype", GH)
_TRACE: dict | None = None


def trace() -> dict:
    global _TRACE
    if _TRACE is None:
        _TRACE = sim_trace(days=1.0)
    return _TRACE


def records(device: int, minutes: range, boot: int = 0, broken: tuple[str, ...] = ()
            ) -> list[tuple[p.Record, float]]:
    """One record a minute of the simulated trace, stamped mid-minute; ``broken`` channels time out."""
    tr = trace()
    out = []
    for k in minutes:
        vals, st = [], []
        for c in p.CHANNELS:
            v = float(tr[c][k])
            ok = math.isfinite(v) and c not in broken
            vals.append(v if ok else None)
            st.append(p.ST_OK if ok else p.ST_TIMEOUT)
        out.append((p.Record(device, boot, k, k * 60_000, 0, 60.0, tuple(vals), tuple(st)),
                    EPOCH + 60 * k + 30))
    return out


@dataclass
class Filled:
    path: Path
    now: float  # gateway time at the end of the fill
    minutes: int


def gh_config(name: str = "north", inside: int = 7, vsensor: str | None = None) -> dict[str, Any]:
    return {"name": name, "farm": "f1", "inside_device": inside, "outside_device": inside,
            "model": "prototype", "config": {"name": name, "greenhouse": "biskra-prototype",
                                             "model": "prototype", "inside": inside,
                                             "outside": inside, "vsensor": vsensor}}


def status_rows(now: float, *, heartbeat: float | None = None, peers: int = 1,
                pending: int = 0, waiting: tuple[str, ...] = (), scale: float = 300.0,
                alarm_at: int = 800,
                ingest: dict[str, int] | None = None, refused: dict | None = None,
                diagnosis: dict | None = None, stopped: float | None = None) -> dict[str, Any]:
    beat = time.time() if heartbeat is None else heartbeat
    rows: dict[str, Any] = {
        "gateway": {"pid": 4242, "started": beat - 3600, "heartbeat": beat, "uptime_s": 3600.0,
                    "clock_now": now, "clock_scale": scale, "farm": "f1", "config": "gw.toml",
                    "passes": 10, "stopped": stopped},
        "zenoh": {"enabled": True, "endpoints": ["tcp/127.0.0.1:7447"], "mode": "peer", "zid": "ab",
                  "peers": peers, "routers": 0, "matched_keys": 5 if peers else 0,
                  "waiting_keys": list(waiting), "published": 1234, "last_put": now,
                  "resent_on_start": 0},
        "outbox": {"pending": pending, "oldest_t": None, "max": 1000, "alarm_at": alarm_at,
                   "alarm": pending >= alarm_at, "full_rounds": 0, "made": {}},
        "ingest": ingest if ingest is not None else {"stored": 150, "duplicate": 2, "bad_tag": 3},
        "greenhouses": {"north": {"state": "running", "cursor": now, "counters": {}}},
        "devices": {"unassigned": []},
    }
    if refused is not None:
        rows["refused"] = refused
    if diagnosis is not None:  # greenhouse → DiagnosisRun.row() (gateway/service/diagnosis.py)
        rows["diagnosis"] = diagnosis
    return rows


def fill_store(path: Path, minutes: int = 150, *, silent_kit: bool = True,
               finding: bool = True, status: bool = True, vsensor: str | None = None) -> Filled:
    """Kit 7 (inside and outside of greenhouse ``north``) for ``minutes``; kit 9 (unassigned)
    sent ten records at the start and fell silent, its rain channel broken."""
    s = Store(path)
    try:
        save_greenhouses(s.conn, [gh_config(vsensor=vsensor)], EPOCH)
        lo, hi = MODEL.bounds(GH)
        outbox = Outbox(s.conn, 100_000, 0.8)
        prod = Producers(s.conn, "f1", {"north": GreenhouseInfo(
            Place("f1", "north", 34.85, 5.73), 7, 7, MODEL, lo.tolist(), hi.tolist())}, outbox)
        s.write_batch(records(7, range(minutes)))
        if silent_kit:
            s.write_batch(records(9, range(10), broken=("rain",)))
        while aggregate(s.conn):
            pass
        now = EPOCH + 60 * minutes + 31
        pipe = GreenhousePipeline("north", GH, MODEL, 7, 7, None, seed=1)
        pipe.resume(s.conn)
        pipe.step_pending(s.conn, now, 0.0, 600.0)
        if finding:
            store_findings(s.conn, "north", [{
                "effect": "heat_source", "start": "2009-11-01T07:00:00Z",
                "params": {"power": 20.0, "unit": "W m-2"}, "summary": "an undeclared heater, 20 W/m²",
                "evidence": "night residual"}], now)
        prod.run()
        prod.snapshots(now, 300.0, {"north": {"estimatorState": "running", "outboxPending": 0,
                                              "outboxAlarm": False, "gatewayUptime": 3600.0,
                                              "storeSize": 1000, "zenohPeers": 1,
                                              "zenohRouters": 0, "ingestCounters": {"stored": 5}}})
        s.conn.execute("UPDATE outbox SET sent = created")  # as if all were published
        if status:
            set_status(s.conn, status_rows(now), now)
    finally:
        s.close()
    return Filled(path, now, minutes)

"""Simulated gateways for the fleet test and bench: many in one process, each with the real parts
between a gateway's store and Zenoh.

    python -m tests.fleet.fleetgw SPEC.json      # commands on stdin, events on stdout (JSON lines)

Each gateway has its own SQLite store (gateway.store.open_db) whose outbox (gateway.store.outbox)
receives kit records replayed from shipped data (training/data/*.csv), turned into
``measurement/inside`` and ``measurement/outside`` messages by the real payload builder
(gateway.publish.payloads.weather_observed) with the idempotency keys the live gateway gives them;
its own Zenoh session in client mode with its farm's certificate, opened as the live gateway
opens it (gateway.net.session.SessionOpener: retried while no router answers); and the real
publisher (gateway.publish.publisher.OutboxPublisher: per-key order, BLOCK, advanced publisher,
puts only while matched). Nothing of the estimator runs.

Commands (one JSON object per line, each answered by an event with the same ``id``):
``{"cmd": "produce", "first": 0, "last": 10, "interval": 0.05}`` adds records first..last-1 to
every gateway, one record per gateway per round, a round every `interval` seconds (a rate, not
a synchronisation), then answers ``produced``; ``{"cmd": "status"}``; ``{"cmd": "stop"}`` stops
the publishers, closes every session and answers ``stopped`` before exiting.
"""

from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from gateway.kitcsv import read_kit_csv
from gateway.net.session import SessionOpener
from gateway.net.zenohcfg import Retry, TlsFiles, session_entries
from gateway.protocol import CHANNELS, ST_NO_SENSOR, ST_OK
from gateway.publish import keyspace as K
from gateway.publish import payloads as P
from gateway.publish import zconfig
from gateway.publish.publisher import OutboxPublisher
from gateway.store.db import open_db, transaction
from gateway.store.outbox import Message, Outbox

GREENHOUSE = "gh1"
DEVICE = 7
BOOT = 0
SIDES = ("inside", "outside")
T0 = 1_790_000_000.0  # [unix s] record seq's time is T0 + 60 seq


def idem(farm: str, side: str, seq: int) -> str:
    """The idempotency key the live gateway gives a kit record's message (producers.py)."""
    return f"{farm}/{GREENHOUSE}/measurement/{side}/{DEVICE}/{BOOT}/{seq}"


def record_messages(place: P.Place, data: dict[str, np.ndarray], row: int, seq: int) -> list[Message]:
    """Kit record `seq` (values from `row` of the shipped data) → its two messages."""
    channels: dict[str, tuple[float | None, int]] = {}
    for c in CHANNELS:
        v = float(data[c][row]) if c in data and math.isfinite(data[c][row]) else None
        channels[c] = (v, ST_OK if v is not None else ST_NO_SENSOR)
    t = T0 + 60 * seq
    reading = P.Reading(DEVICE, BOOT, seq, t, channels)
    out = []
    for side in SIDES:
        kind = f"measurement/{side}"
        key = idem(place.farm, side, seq)
        out.append(Message(K.key(place.farm, GREENHOUSE, kind), kind, t, key,
                           P.dumps(P.weather_observed(place, side, reading, key))))
    return out


class SimGateway:
    def __init__(self, spec: dict[str, Any], ca: str, data: dict[str, np.ndarray], offset: int,
                 cache: int, retry: Retry) -> None:
        self.farm, self.db, self.data, self.offset = spec["farm"], Path(spec["db"]), data, offset
        self.place = P.Place(self.farm, GREENHOUSE, 52.0, 4.5)
        self.conn = open_db(self.db, durable=False)
        self.lock = threading.Lock()  # the connection serves the producer and status threads
        self.outbox = Outbox(self.conn)
        self.cache = cache
        self.publisher: OutboxPublisher | None = None
        connect = list(spec["connect"])
        extra = session_entries(connect, (), TlsFiles(Path(ca), Path(spec["cert"]), Path(spec["key"])),
                                retry)
        self.opener = SessionOpener(lambda: zconfig.build("client", connect, extra=extra),
                                    self._attach, retry, what=f"{self.farm}")
        self.n = len(next(iter(data.values())))

    def start(self) -> None:
        self.opener.start()

    def _attach(self, session: Any) -> None:
        self.publisher = OutboxPublisher(session, self.db, cache=self.cache, mode="client")
        self.publisher.start()

    def produce(self, seq: int) -> None:
        msgs = record_messages(self.place, self.data, (self.offset + seq) % self.n, seq)
        with self.lock, transaction(self.conn):
            self.outbox.add(msgs)
        if self.publisher is not None:
            self.publisher.kick()

    def status(self) -> dict[str, Any]:
        session = self.opener.session
        pub = self.publisher
        with self.lock:
            pending = self.outbox.pending()
        return {"farm": self.farm, "open": session is not None, "pending": pending,
                "published": pub.state.published if pub else 0,
                "matched": pub.state.matched_keys if pub else 0,
                "routers": [str(z) for z in session.info.routers_zid()] if session else [],
                "error": str(pub.error) if pub and pub.error else ""}

    def stop(self) -> dict[str, Any]:
        """Stop the publisher (its last drain done), then close; returns the final status."""
        session = self.opener.stop()
        if self.publisher is not None:
            self.publisher.stop()
        final = self.status()
        if session is not None:
            session.close()
        self.conn.close()
        return final


def usage() -> dict[str, float]:
    """This process's CPU seconds (all threads) and memory [MB]."""
    t = os.times()
    mem = {}
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(("VmRSS:", "VmHWM:")):
                mem[line.split(":")[0]] = int(line.split()[1]) / 1024
    return {"cpu_s": t.user + t.system, "rss_mb": mem.get("VmRSS", 0.0), "hwm_mb": mem.get("VmHWM", 0.0)}


class Worker:
    def __init__(self, spec: dict[str, Any]) -> None:
        kit = read_kit_csv(spec["data"])
        data = {c: np.asarray(v, dtype=float) for c, v in kit.columns.items()}
        retry = Retry(*spec.get("retry_ms", (100, 500)))
        self.base = usage()  # before any session: the process's own cost
        self.gateways = [SimGateway(g, spec["ca"], data, g["offset"], spec.get("cache", 256), retry)
                         for g in spec["gateways"]]
        self._out = threading.Lock()

    def emit(self, event: dict[str, Any]) -> None:
        with self._out:
            sys.stdout.write(json.dumps(event) + "\n")
            sys.stdout.flush()

    def produce(self, cmd: dict[str, Any]) -> None:
        nxt = time.monotonic()
        for seq in range(cmd["first"], cmd["last"]):
            for gw in self.gateways:
                gw.produce(seq)
            nxt += cmd.get("interval", 0.0)
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing the replay (a rate), not waiting for anything
        self.emit({"event": "produced", "id": cmd.get("id")})

    def run(self) -> int:
        for gw in self.gateways:
            gw.start()
        self.emit({"event": "ready", "gateways": len(self.gateways), "base": self.base})
        producers: list[threading.Thread] = []
        for line in sys.stdin:
            cmd = json.loads(line)
            if cmd["cmd"] == "produce":
                t = threading.Thread(target=self.produce, args=(cmd,), daemon=True)
                t.start()
                producers.append(t)
            elif cmd["cmd"] == "status":
                self.emit({"event": "status", "id": cmd.get("id"), "usage": usage(),
                           "gateways": [gw.status() for gw in self.gateways]})
            elif cmd["cmd"] == "stop":
                break
        for t in producers:
            t.join()
        final = [gw.stop() for gw in self.gateways]
        self.emit({"event": "stopped", "id": None, "usage": usage(), "gateways": final})
        return 0


def main(argv: list[str]) -> int:
    spec = json.loads(Path(argv[0]).read_text())
    return Worker(spec).run()


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

"""The gateway SIGKILLed 10 times mid-stream and restarted: no acknowledged sample lost, no
message lost (the cloud's copy equals the gateway's outbox, repeats dropped), the estimator
resumes from its saved state (no minute stepped twice, never started anew). The cloud listens
and the gateway connects to it (peer mode), so every restart finds it at the same endpoint."""

from __future__ import annotations

import os
import random
import signal
import sqlite3
import time
from pathlib import Path

from gateway.cloud.store import SqliteCloudStore
from gateway.cloud.subscriber import Subscriber
from gateway.publish import zconfig
from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, wait_for, write_config
from training.kitsim import KitClock

SCALE = 300.0
KILLS = 10


def q(db: Path, sql: str) -> list[tuple]:
    with sqlite3.connect(db) as c:
        return c.execute(sql).fetchall()


def test_sigkill_10_times_mid_stream(tmp_path: Path) -> None:
    rng = random.Random(9)
    clock = KitClock(SCALE, EPOCH)
    db = tmp_path / "gw.db"
    kit = PyKit(7, sim_trace(), clock.now, window=128)
    cloud = SqliteCloudStore(tmp_path / "cloud.db")
    before = zconfig.listening_ports()
    sub = Subscriber(cloud, listen=["tcp/127.0.0.1:0"])
    gw = None
    try:
        sub.start()
        (endpoint,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        cfg = write_config(tmp_path, anchor=clock.anchor, scale=SCALE, zenoh_listen="",
                           zenoh_connect=endpoint, status_every_s=900)
        cfg.write_text(cfg.read_text().replace('listen = [""]', "listen = []"))
        gw = GatewayProcess(cfg)
        in_flight = []
        for _ in range(KILLS):
            gw.start()
            t_end = time.monotonic() + rng.uniform(0.2, 0.75)
            while time.monotonic() < t_end:
                kit.pump(gw.udp)
            # kill mid-stream by construction: the next record is sent and SIGKILL follows it
            wait_for(lambda: kit.t(kit.next) <= kit.now() or kit.pump(gw.udp), 30, "a record due")
            kit.send_due(gw.udp)
            in_flight.append(len(kit.unacked))
            assert gw.proc is not None
            os.kill(gw.proc.pid, signal.SIGKILL)
            gw.proc.wait(timeout=30)
            gw.proc = None
            stored = {r[0] for r in q(db, "SELECT seq FROM samples")}
            assert kit.acked <= stored, f"acknowledged but lost: {sorted(kit.acked - stored)[:10]}"
        assert all(n > 0 for n in in_flight), in_flight
        gw.start()
        last = kit.next
        wait_for(lambda: kit.acked >= set(range(last)) or kit.pump(gw.udp), 90, "every record acked")
        final_minute = EPOCH + 60 * (last - 2)
        wait_for(lambda: (q(db, "SELECT minute FROM estimator_state") or [(0,)])[0][0] >= final_minute,
                 90, "the estimator to catch up")
        wait_for(lambda: not q(db, "SELECT 1 FROM outbox WHERE sent IS NULL LIMIT 1"), 90,
                 "the outbox to drain")
        assert gw.stop() == 0
        outbox = q(db, "SELECT id, key, idem FROM outbox ORDER BY id")
        wait_for(lambda: sub.wait_idle(1.0) and cloud.count() >= len(outbox), 90,
                 "the cloud to have every message")
    finally:
        if gw is not None:
            gw.kill()
        sub.stop()
        kit.close()
    # samples: every acknowledged one, once; the file is sound
    seqs = [r[0] for r in q(db, "SELECT seq FROM samples")]
    assert len(seqs) == len(set(seqs)) and set(seqs) >= kit.acked >= set(range(last))
    assert q(db, "PRAGMA integrity_check") == [("ok",)]
    # messages: the cloud's copy is the outbox, each once, first arrivals in order per key
    cloud_msgs = list(cloud.messages())
    assert [m.idem for m in cloud_msgs if m.idem not in {r[2] for r in outbox}] == []
    assert {m.idem for m in cloud_msgs} == {r[2] for r in outbox}
    order = {r[2]: r[0] for r in outbox}
    for key in {m.key for m in cloud_msgs}:
        ids = [order[m.idem] for m in cloud_msgs if m.key == key]
        assert ids == sorted(ids), f"{key} out of order"
    measured = [m for m in cloud_msgs if m.kind == "measurement/inside"]
    assert len(measured) == len(set(seqs))
    # the estimator resumed from its state every time: each minute stepped once, never anew
    dup = q(db, "SELECT count(*) FROM (SELECT t, name FROM estimates WHERE source='online' "
                "GROUP BY t, name HAVING count(*) > 1)")
    assert dup == [(0,)]
    log = (tmp_path / "gateway.log").read_text()
    starts = [line for line in log.splitlines() if "new estimator" in line or "resumed at" in line]
    assert len(starts) == KILLS + 1
    first = next(i for i, line in enumerate(starts) if "resumed" in line)
    assert all("resumed" in line for line in starts[first:])  # once saved, always resumed
    resumed_at = [line.split("resumed at ")[1][:17] for line in starts[first:]]
    assert resumed_at == sorted(resumed_at) and len(starts) - first >= KILLS // 2
    assert "not used" not in log and "Traceback" not in log
    cloud.close()

"""End to end on loopback: the real firmware under MicroPython, its sensors fed by the reference
simulator at 300× (training/kitsim) → ``python -m gateway run`` → a Zenoh subscriber storing into
its own SQLite. Measurements, forecasts, parameters and fluxes arrive; the subscriber's copy
equals the gateway's store; every payload validates; history answers over Zenoh; SIGTERM stops
everything cleanly."""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from gateway import protocol as p
from gateway.cloud.store import SqliteCloudStore
from gateway.cloud.subscriber import Subscriber, export_kit_csv
from gateway.kitcsv import read_kit_csv
from gateway.publish import validate
from gateway.store.export import export_kit_csv as gateway_export
from tests.gateway_harness import EPOCH, KEY, GatewayProcess, wait_for, write_config
from training.kitsim import KitClock, SimKit, micropython, simulated_trace

pytestmark = pytest.mark.skipif(micropython() is None, reason="micropython not installed")
SCALE = 300.0


def gw_count(db: Path, sql: str) -> int:
    with contextlib.closing(sqlite3.connect(db)) as c:  # closed now, not at a garbage collection
        return c.execute(sql).fetchone()[0]


def test_kit_to_gateway_to_cloud(tmp_path: Path) -> None:
    clock = KitClock(SCALE, EPOCH)
    cfg = write_config(tmp_path, anchor=clock.anchor, scale=SCALE, status_every_s=1200)
    db = tmp_path / "gw.db"
    trace = simulated_trace(tmp_path / "trace.txt", start="2009-11-01", days=1.0)
    gw = GatewayProcess(cfg)
    cloud = SqliteCloudStore(tmp_path / "cloud.db")
    sub = kit = None
    try:
        gw.start()
        sub = Subscriber(cloud, [gw.zenoh])
        sub.start()
        kit = SimKit(tmp_path / "board", 7, KEY, gw.udp, trace, clock)
        kit.start()
        wait_for(lambda: gw_count(db, "SELECT count(*) FROM outbox WHERE kind='forecast'") >= 30,
                 120, "30 forecasts from the live estimator")
        assert kit.alive(), "\n".join(kit.lines[-20:])
        # history over Zenoh, answered from the gateway's store while it runs
        replies = list(sub.session.get(  # type: ignore[union-attr]
            "serra/f1/north/history/measurement/inside?limit=5",
            consolidation=zenoh.ConsolidationMode.NONE))
        seqs = [json.loads(r.ok.payload.to_string())["kitRecord"]["value"]["seq"] for r in replies]
        assert seqs == [0, 1, 2, 3, 4]
        kit.stop()
        assert gw.stop() == 0  # SIGTERM: committed, acknowledged, published, closed
        # the store is one file again: the WAL checkpointed, emptied and removed by the last close
        files = {f.name: f.stat().st_size for f in tmp_path.glob("gw.db*")}
        assert list(files) == ["gw.db"], files
        wait_for(lambda: sub.wait_idle(1.0) and cloud.count() >= gw_count(
            db, "SELECT count(*) FROM outbox"), 60, "the cloud to have every message")
    finally:
        if kit is not None:
            kit.stop()
        if sub is not None:
            sub.stop()
        gw.kill()
    log = (tmp_path / "gateway.log").read_text()
    assert "Traceback" not in log and "ERROR" not in log, log[-3000:]
    # the firmware's records arrived once each, with their values
    with sqlite3.connect(db) as c:
        cols = ", ".join(f"{ch}, {ch}_st" for ch in p.CHANNELS)
        stored = {r[0]: r[1:] for r in c.execute(f"SELECT seq, {cols} FROM samples WHERE boot=0")}
        outbox = {r[0]: r[1:] for r in c.execute("SELECT idem, key, payload, sent FROM outbox")}
    recs = {seq: v for (boot, seq), v in kit.records().items() if boot == 0}
    assert len(stored) >= 30 and set(stored) <= set(recs)
    for seq, row in stored.items():
        for i, (raw, st) in enumerate(recs[seq]):
            assert row[2 * i + 1] == st
            assert row[2 * i] == (None if st >= 0x10 else pytest.approx(raw * p.SCALES[i]))
    # the subscriber's copy equals the gateway's store, message for message
    copy = {m.idem: (m.key, m.payload) for m in cloud.messages()}
    assert all(sent is not None for _, _, sent in outbox.values())
    assert copy == {k: (key, payload) for k, (key, payload, _) in outbox.items()}
    kinds = {m.kind for m in cloud.messages()}
    assert {"measurement/inside", "measurement/outside", "forecast", "parameters", "fluxes",
            "status", "device/7"} <= kinds
    by_kind: dict[str, list[dict]] = {}
    for m in cloud.messages():
        by_kind.setdefault(m.kind, []).append(json.loads(m.payload))
    for kind, docs in by_kind.items():
        for doc in docs[:: max(1, len(docs) // 15)]:
            assert validate.errors(doc) == [], kind
    fc = by_kind["forecast"][-1]
    assert fc["outlook"]["value"] == "clear-sky-trend"  # the default for a greenhouse with a [site]
    assert [f["horizon"]["value"] for f in fc["airTemperatureForecast"]] == [15, 30, 60]
    # the kit CSV rebuilt from the cloud's copy equals the gateway's own export, minute by minute
    export_kit_csv(cloud, "f1", "north", tmp_path / "cloud.csv")
    with sqlite3.connect(db) as c:
        gateway_export(c, tmp_path / "gw.csv", 7)
    a, b = read_kit_csv(tmp_path / "cloud.csv"), read_kit_csv(tmp_path / "gw.csv")
    assert len(a.time) == len(b.time) >= 30 and np.array_equal(a.time, b.time)
    for col in ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "rain"):
        np.testing.assert_allclose(a.columns[col], b.columns[col], atol=1e-6, err_msg=col)
    cloud.close()
    assert time.time() - clock.anchor < 600

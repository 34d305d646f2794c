"""The daily diagnosis in the running gateway, end to end: ``python -m gateway run`` with
``[diagnosis]`` on, on a store that already holds 42 h of a kit's minutes, runs a real diagnosis
(the ``diagnose --json`` subprocess the scheduler starts), keeps the run (``meta`` and the
status row), publishes it (kind ``diagnosis``, answered by the history queryable), and the
status screen shows the same run whether it reads the store or the gateway over Zenoh,
``status --once`` asking for attention for its warning either way.

The run is made due at once by the store's ``diagnosis_last`` (the scheduler's own record of its
last run, as a gateway that last ran the diagnosis a day ago would have it): no sleeping, no
test hook. The kit's clock is 12 h off, so the run is ok with a ``site_time_mismatch`` warning."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import time
from contextlib import closing
from pathlib import Path

from gateway.publish import validate
from gateway.status.snapshot import attention
from gateway.status.store_source import StoreSource
from gateway.status.zenoh_source import ZenohSource
from gateway.store import Store
from gateway.store.live import read_status
from tests.gateway_harness import EPOCH, GatewayProcess, shifted_kit, wait_for, write_config


def read(db: Path, sql: str) -> list[tuple]:
    with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as c:
        return c.execute(sql).fetchall()


def status_once(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", "status", *args, "--once"],
                          capture_output=True, text=True, timeout=120)


def test_the_running_gateway_diagnoses_keeps_and_publishes_the_run(tmp_path: Path) -> None:
    db = tmp_path / "gw.db"
    end = shifted_kit(db)
    store = Store(db)
    store.set_meta("diagnosis_last", repr(end - 25 * 3600))  # the last run a day ago: one is due
    store.close()
    # the gateway clock at real speed, reading the end of the stored data as it starts
    cfg = write_config(tmp_path, anchor=time.time() - (end - EPOCH), scale=1.0,
                       diagnosis="every_hours = 24\ndays = 2.0\nmin_days = 1.5\ntimeout_s = 600")
    gw = GatewayProcess(cfg)
    source = None
    try:
        gw.start()
        kept = wait_for(lambda: read(db, "SELECT value FROM meta WHERE name='diagnosis_run/north'"),
                        300, "the scheduler to keep its run")
        run = json.loads(kept[0][0])
        assert run["ok"] is True and run["when"] >= end, run
        assert run["note"].startswith("diagnosis of 1.8 days in ") and run["findings"] == 0
        assert [n["code"] for n in run["notes"] if n["level"] == "warning"] == [
            "site_time_mismatch"]
        # the round's time is recorded after every greenhouse's run is kept: wait for it
        wait_for(lambda: float(read(db, "SELECT value FROM meta WHERE name='diagnosis_last'")[0][0])
                 == run["when"], 60, "the scheduler to record its round (the next run one period on)")
        # published: one message of the run, through the outbox (its store-and-forward)
        (payload,) = wait_for(lambda: read(db, "SELECT payload FROM outbox WHERE "
                                               "key='serra/f1/north/diagnosis'"),
                              60, "the worker to make the diagnosis message")
        doc = json.loads(payload[0])
        assert validate.errors(doc) == []
        assert (doc["succeeded"]["value"], doc["summary"]["value"], doc["runNotes"]["value"]) == (
            True, run["note"], run["notes"])
        # the status row the service writes (every 5 s) holds the run
        row = wait_for(lambda: _status_run(db), 60, "the status row to hold the run")
        assert row == run
        # the screen over Zenoh (history queries) shows what the store's screen shows
        source = ZenohSource([gw.zenoh])
        over = wait_for(lambda: source.snapshot().gateway.diagnosis.get("north"), 60,
                        "the screen over Zenoh to show the run")
        local = StoreSource(db)
        try:
            assert over == local.snapshot().gateway.diagnosis["north"]
        finally:
            local.close()
        assert over.ok and [c for c, _ in over.warnings] == ["site_time_mismatch"]
        assert "diagnosis of north warns: site_time_mismatch" in attention(source.snapshot())
        for how in (("--connect", gw.zenoh), ("--db", str(db))):
            r = status_once(*how)
            assert r.returncode == 1, r.stdout + r.stderr
            assert "ATTENTION: diagnosis of north warns: site_time_mismatch" in r.stdout, how
        source.close()
        source = None
        assert gw.stop() == 0
    finally:
        if source is not None:
            source.close()
        gw.kill()
    log = (tmp_path / "gateway.log").read_text()
    assert "Traceback" not in log and "ERROR" not in log, log[-3000:]
    assert "greenhouse north: diagnosis of 1.8 days in " in log


def _status_run(db: Path) -> dict | None:
    with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as c:
        row = read_status(c).get("diagnosis", ({}, 0.0))[0]
    return row.get("north")

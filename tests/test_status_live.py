"""The status screen against a live gateway (a real ``python -m gateway run`` fed by a firmware-like
kit on the 300× test clock): over Zenoh it shows what the store shows, and it drains nothing."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from gateway.status.messages import Messages
from gateway.status.snapshot import Link
from gateway.status.zenoh_source import ZenohSource
from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, wait_for, write_config
from tests.status_store import trace
from training.kitsim import KitClock

SCALE = 300.0


def count(db: Path, sql: str) -> int:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        return c.execute(sql).fetchone()[0]


def status(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", "status", *args, "--once"],
                          capture_output=True, text=True, timeout=120)


def test_status_over_zenoh_shows_the_gateway_and_drains_nothing(tmp_path: Path) -> None:
    clock = KitClock(SCALE, EPOCH)
    cfg = write_config(tmp_path, anchor=clock.anchor, scale=SCALE)
    db = tmp_path / "gw.db"
    gw = GatewayProcess(cfg)
    kit = PyKit(7, {c: np.asarray(v) for c, v in trace().items()}, clock.now)
    stop = threading.Event()

    def send() -> None:
        while not stop.is_set():
            kit.pump(gw.udp)

    pump = threading.Thread(target=send)
    source = None
    try:
        gw.start()
        pump.start()
        wait_for(lambda: count(db, "SELECT count(*) FROM outbox WHERE kind='forecast'") >= 65, 120,
                 "65 forecasts (a 60-min forecast scored)")
        # nobody subscribes: every message is held in the outbox
        assert count(db, "SELECT count(*) FROM outbox WHERE sent IS NOT NULL") == 0
        r = status("--connect", gw.zenoh)
        assert r.returncode == 0, r.stdout + r.stderr
        out = r.stdout
        for want in ("farm f1 · greenhouse north (1/1)", "Inside T  measured", "+60 min",
                     "Parameters (prototype", "   7  north in+out", "all 7 channels ok",
                     "Service    answering", "this screen: connected (1 peer), the gateway answers"):
            assert want in out, want
        assert "\x1b" not in out
        # the data layer in process: the store and the messages agree on the latest forecast.
        # The kit runs on (300x): read the store first, then the screen must catch up with it
        # (a snapshot taken first and compared with a later store read raced the gateway).
        source = ZenohSource([gw.zenoh])
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
            t = c.execute("SELECT max(t) FROM estimates WHERE source='forecast'").fetchone()[0]

        def caught_up():
            (view,) = source.snapshot().greenhouses
            ok = view.temperature.t is not None and view.temperature.t >= t - 60 * 3
            return view if ok else None

        g = wait_for(caught_up, 60, "the screen's latest forecast as recent as the store's")
        assert sorted(g.temperature.forecasts) == [15, 30, 60]
        assert [s.n > 0 for s in g.temperature.skill] == [True, True, True]
        assert len(g.series["t_in"].finite) > 10
        again = source.snapshot()  # the next refresh asks only for what is new
        assert again.greenhouses[0].temperature.t >= g.temperature.t
        # asking is not listening: the gateway marked nothing sent
        assert count(db, "SELECT count(*) FROM outbox WHERE sent IS NOT NULL") == 0
        stop.set()
        pump.join()
        assert gw.stop() == 0
    finally:
        stop.set()
        if pump.is_alive():
            pump.join()
        if source is not None:
            source.close()
        kit.close()
        gw.kill()


def test_status_over_zenoh_with_nobody_there() -> None:
    r = status("--connect", "tcp/127.0.0.1:9")  # discard port: nothing listens
    assert r.returncode == 1, r.stderr
    assert r.stdout.startswith("ATTENTION: no gateway answers over Zenoh\nATTENTION: the Zenoh link")
    assert "this screen: nobody reachable at tcp/127.0.0.1:9" in r.stdout
    # the endpoint is the one it dials, not one anybody listens on; there is no store either
    assert "listening on" not in r.stdout and "No greenhouse yet." in r.stdout, r.stdout
    assert "in this store" not in r.stdout, r.stdout
    assert "no message from a gateway yet" in r.stdout
    assert Messages().snapshot("x", 0.0, None, Link()).greenhouses == ()

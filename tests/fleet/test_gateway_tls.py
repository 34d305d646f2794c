"""The live gateway in the fleet, on loopback: ``python -m gateway run`` in client mode with its
farm's certificate ([zenoh.tls]) starts while no router answers (ingest and the estimator run,
the outbox holds, its session open is retried), then publishes through a mutual-TLS router with
access control to ``python -m gateway subscribe`` storing into PostgreSQL; after the gateway has
stopped, history is answered by the cloud store."""

from __future__ import annotations

import json
import signal
import sqlite3
from contextlib import ExitStack
from pathlib import Path

import psycopg
import pytest
import zenoh

from gateway.store.live import read_status
from tests.fleet.conftest import ACCESS
from tests.fleet.kit import (
    LineProc,
    Pki,
    RouterProc,
    free_port,
    open_client,
    subscriber_argv,
    wait_until,
    write_router_toml,
)
from tests.fleet.pg import PgCluster
from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, write_config
from training.kitsim import KitClock

SCALE = 300.0
SCHEMA = "t_gateway_tls"


def client_config(cfg: Path, pki: Pki, farm: str, endpoint: str) -> None:
    """The [zenoh] table of a gateway that is a TLS client of one router."""
    tls = pki.tls(farm)
    text = cfg.read_text()
    start = text.index("[zenoh]")
    end = text.index("[diagnosis]")
    cfg.write_text(text[:start] + f"""[zenoh]
mode = "client"
connect = ["{endpoint}"]
retry_initial_ms = 100
retry_max_ms = 500
resend_on_start_s = 2.0
[zenoh.tls]
ca = "{tls.ca}"
cert = "{tls.cert}"
key = "{tls.key}"
""" + text[end:])


def zenoh_status(db: Path) -> dict:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        return read_status(c).get("zenoh", ({}, 0))[0]


def outbox(db: Path) -> list[tuple[int, str, str, float | None]]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as c:
        return c.execute("SELECT id, key, idem, sent FROM outbox ORDER BY id").fetchall()


def pg_rows(pg: PgCluster) -> list[tuple[int, str, str]]:
    with psycopg.connect(pg.dsn) as c:
        try:
            return c.execute(f"SELECT id, key, idem FROM {SCHEMA}.message ORDER BY id").fetchall()
        except psycopg.errors.UndefinedTable:
            return []


def pump(kit: PyKit, addr: tuple[str, int], records: int, timeout: float = 120) -> None:
    """Let the kit send until `records` records are acknowledged."""
    wait_until(lambda: kit.pump(addr) or len(kit.acked) >= records, timeout,
               f"{records} kit records acknowledged", interval=0)


@pytest.fixture()
def schema(pg: PgCluster):
    yield SCHEMA
    with psycopg.connect(pg.dsn, autocommit=True) as c:
        c.execute(f"DROP SCHEMA IF EXISTS {SCHEMA} CASCADE")


def test_a_tls_client_gateway_waits_for_its_router_then_reaches_the_postgres_store(
        pki: Pki, pg: PgCluster, schema: str, tmp_path: Path) -> None:
    port = free_port()  # the router's port: nothing answers there yet
    endpoint = f"tls/127.0.0.1:{port}"
    clock = KitClock(SCALE, EPOCH)
    cfg = write_config(tmp_path, anchor=clock.anchor, scale=SCALE, farm="farm-a", status_every_s=600)
    client_config(cfg, pki, "farm-a", endpoint)
    db = tmp_path / "gw.db"
    kit = PyKit(7, sim_trace(0.5), clock.now)
    gw = GatewayProcess(cfg)
    with ExitStack() as stack:
        stack.callback(kit.close)
        stack.callback(gw.kill)
        gw.start()  # ready without a router: ingest and the estimator do not need one
        pump(kit, gw.udp, 10)
        wait_until(lambda: len([r for r in outbox(db) if r[3] is None]) >= 10, what="messages held")
        status = wait_until(lambda: (s := zenoh_status(db)).get("attempts", 0) >= 2 and s,
                            what="the gateway retrying its session open")
        assert status["connecting"] and not status["open"]
        assert "Unable to connect to any of" in status["last_error"]
        assert all(r[3] is None for r in outbox(db))  # nothing was sent: nobody to send to

        router = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "cloud.toml", "cloud", pki, listen=[endpoint], access=ACCESS)))
        sub = stack.enter_context(LineProc(subscriber_argv(
            pki, "store", router.endpoints, "--farm", "farm-a", "--farm", "farm-b",
            "--dsn", pg.dsn, "--schema", schema, "--history"), "serra-subscribe ready",
            tmp_path / "subscribe.log"))
        wait_until(lambda: zenoh_status(db).get("matched_keys", 0) >= 2, what="the gateway's "
                   "session open and its publisher matching the store through the router")
        pump(kit, gw.udp, 20)
        assert gw.stop() == 0  # SIGTERM: what was made is put, then the session closes
        final = outbox(db)
        assert all(r[3] is not None for r in final)
        wait_until(lambda: len(pg_rows(pg)) >= len(final), what="every message in PostgreSQL")
        rows = pg_rows(pg)
        assert sorted(r[2] for r in rows) == sorted(r[2] for r in final)  # each once
        order = {r[2]: r[0] for r in final}
        for key in {r[1] for r in final}:
            ids = [order[r[2]] for r in rows if r[1] == key]  # the store's arrival order
            assert ids == sorted(ids), f"{key}: out of order"

        # The gateway is gone: history comes from the cloud store, through the router, to a
        # reader with rights on farm-a (the store has rights to answer, `store = true`).
        with open_client(pki, "reader-a", router.endpoints) as reader:
            replies = wait_until(lambda: list(reader.get(
                "serra/farm-a/north/history/measurement/inside?limit=5",
                consolidation=zenoh.ConsolidationMode.NONE, timeout=10.0)), what="history replies")
        docs = [json.loads(r.ok.payload.to_string()) for r in replies]
        assert [str(r.ok.key_expr) for r in replies] == ["serra/farm-a/north/history/measurement/inside"] * 5
        assert [d["kitRecord"]["value"]["seq"] for d in docs] == [0, 1, 2, 3, 4]
        assert sub.stop() == 0
    log = (tmp_path / "gateway.log").read_text()
    assert "cannot open the session (Unable to connect to any of [tls/127.0.0.1:" in log
    assert "session open after" in log
    assert "Traceback" not in log
    assert "messages in the store" in sub.text()


def test_the_postgres_history_survives_a_subscriber_killed_mid_stream(
        pki: Pki, pg: PgCluster, schema: str, tmp_path: Path) -> None:
    """The cloud subscriber SIGKILLed while the gateway publishes (a batch may be received and
    not yet committed), records made while it is away, then a new subscriber: its catch-up from
    the gateway's history and the gateway's drain leave PostgreSQL with every message once."""
    clock = KitClock(SCALE, EPOCH)
    cfg = write_config(tmp_path, anchor=clock.anchor, scale=SCALE, farm="farm-a", status_every_s=600)
    db = tmp_path / "gw.db"
    kit = PyKit(7, sim_trace(0.5), clock.now)
    with ExitStack() as stack:
        router = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "cloud.toml", "cloud", pki, access=ACCESS)))
        argv = subscriber_argv(pki, "store", router.endpoints, "--farm", "farm-a", "--dsn", pg.dsn,
                               "--schema", schema)
        first = stack.enter_context(LineProc(argv, "serra-subscribe ready", tmp_path / "sub1.log"))
        client_config(cfg, pki, "farm-a", router.endpoints[0])
        gw = GatewayProcess(cfg)
        stack.callback(kit.close)
        stack.callback(gw.kill)
        gw.start()
        wait_until(lambda: zenoh_status(db).get("matched_keys", 0) >= 2, what="the store matching")
        pump(kit, gw.udp, 10)
        wait_until(lambda: pg_rows(pg), what="rows in PostgreSQL")
        pump(kit, gw.udp, 15)
        first.stop(sig=signal.SIGKILL)  # mid-stream: whatever it held uncommitted is gone with it
        pump(kit, gw.udp, 25)  # made while no subscriber listens: the gateway holds them
        second = stack.enter_context(LineProc(argv, "serra-subscribe ready", tmp_path / "sub2.log"))
        pump(kit, gw.udp, 30)
        assert gw.stop() == 0
        final = outbox(db)
        assert all(r[3] is not None for r in final)
        wait_until(lambda: len(pg_rows(pg)) >= len(final), what="every message in PostgreSQL")
        assert second.stop() == 0
    rows = pg_rows(pg)
    assert len(rows) == len(final)  # none twice ...
    assert sorted(r[2] for r in rows) == sorted(r[2] for r in final)  # ... and none lost
    assert "caught up 0," not in second.text()  # the new subscriber asked the gateway's history


def test_a_gateway_the_routers_access_table_does_not_list_says_so_and_holds(
        pki: Pki, tmp_path: Path) -> None:
    """Farm C's certificate is from the fleet CA, but [access].gateways lists farm-a and farm-b
    only: its TLS link opens, the cloud store subscribes to serra/farm-c/**, and still nothing
    flows (the router never tells the gateway of that subscription). The gateway's log says
    so once, naming the zid that the router's refusal line names."""
    if "farm-c" not in pki.issued:
        pki.add("gateway", "farm-c")
    clock = KitClock(SCALE, EPOCH)
    cfg = write_config(tmp_path, anchor=clock.anchor, scale=SCALE, farm="farm-c", status_every_s=600)
    db = tmp_path / "gw.db"
    kit = PyKit(7, sim_trace(0.5), clock.now)
    with ExitStack() as stack:
        router = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "cloud.toml", "cloud", pki, access=ACCESS)))
        stack.enter_context(LineProc(subscriber_argv(
            pki, "store", router.endpoints, "--farm", "farm-c", "--db", str(tmp_path / "cloud.db")),
            "serra-subscribe ready", tmp_path / "subscribe.log"))
        client_config(cfg, pki, "farm-c", router.endpoints[0])
        gw = GatewayProcess(cfg)
        stack.callback(kit.close)
        stack.callback(gw.kill)
        gw.start()
        pump(kit, gw.udp, 3)
        log = tmp_path / "gateway.log"
        said = wait_until(lambda: next((x for x in log.read_text().splitlines()
                                        if "nobody listens to the" in x), ""),
                          what="the gateway saying nobody listens")
        zid = zenoh_status(db)["zid"]
        assert "linked to 1 router(s)" in said and "[access].gateways" in said and zid in said
        wait_until(lambda: f"{zid} did not match any configured ACL subject" in router.log_text(),
                   what="the router's refusal line naming the same zid")
        assert gw.stop() == 0
    assert all(r[3] is None for r in outbox(db))  # held, not lost
    assert sum("nobody listens" in x for x in log.read_text().splitlines()) == 1  # said once

"""The cloud store's PostgreSQL going down under a running subscriber, as an operator sees it: the
real server stopped and started again (the session's throwaway cluster), real Zenoh sessions on
loopback. What arrives meanwhile is held and stored once the server is back; the log says so in
one line when it fails and one when it is back (at the default level, not one per retry); stopped
while the server is down, ``python -m gateway subscribe`` exits 2 saying how many messages it
could not store (no traceback)."""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest
import zenoh

from gateway.cloud.postgres import PgStore
from gateway.cloud.subscriber import Subscriber
from gateway.publish import zconfig
from tests.fleet.kit import LineProc, free_port, wait_until
from tests.fleet.pg import PgCluster
from tests.fleet.test_cloud_history import message

SCHEMA = "t_outage"


def stored(pg: PgCluster) -> list[str]:
    """The idempotency keys in the store, in arrival order ([] while the schema is missing)."""
    with psycopg.connect(pg.dsn) as c:
        try:
            return [r[0] for r in c.execute(f"SELECT idem FROM {SCHEMA}.message ORDER BY id")]
        except psycopg.errors.UndefinedTable:
            return []


@pytest.fixture()
def outage(pg: PgCluster) -> Iterator[PgCluster]:
    """The session's cluster, which the test may stop; running again and the schema gone after."""
    yield pg
    if not pg.running:
        pg.start_server()
    with psycopg.connect(pg.dsn, autocommit=True) as c:
        c.execute(f"DROP SCHEMA IF EXISTS {SCHEMA} CASCADE")


def publisher(session: zenoh.Session) -> zenoh.Publisher:
    pub = session.declare_publisher("serra/farm-a/gh1/forecast",
                                    congestion_control=zenoh.CongestionControl.BLOCK)
    wait_until(lambda: pub.matching_status.matching, what="the subscriber matching")
    return pub


def test_messages_arriving_while_postgres_is_down_are_held_and_stored_when_it_is_back(
        outage: PgCluster, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    store = PgStore.connect(outage.dsn, schema=SCHEMA)
    listen = ["tcp/127.0.0.1:0"]
    before = zconfig.listening_ports()
    sub = Subscriber(store, listen=listen, keys=["serra/farm-a/**"])
    try:
        sub.start()
        (endpoint,) = zconfig.resolve_listen(listen, before)
        with zenoh.open(zconfig.build("peer", connect=[endpoint])) as gw:
            pub = publisher(gw)
            pub.put(message("farm-a", "gh1", "forecast", 0).payload)
            wait_until(lambda: len(stored(outage)) == 1, what="the first message stored")
            outage.stop_server()
            pub.put(message("farm-a", "gh1", "forecast", 1).payload)
            wait_until(lambda: sub.stats.store_retries >= 2, what="two refused attempts")
            pub.put(message("farm-a", "gh1", "forecast", 2).payload)
            # counted on arrival: the operator's stats line shows what is held
            wait_until(lambda: sub.stats.received == 3, what="the third message received")
            assert sub.stats.stored == 1
            outage.start_server()
            wait_until(lambda: len(stored(outage)) == 3, what="the held messages stored")
            pub.undeclare()
    finally:
        sub.stop()
        store.close()
    assert sub.error is None and sub.stats.stored == 3 and sub.stats.repeats == 0
    assert stored(outage) == [f"farm-a/gh1/forecast/{i}" for i in range(3)]
    said = [(r.levelno, r.getMessage()) for r in caplog.records if r.name.startswith("serra.cloud")]
    # one line when it fails and one when it is back, however many attempts were refused
    assert len([m for _, m in said if "PostgreSQL connection lost" in m]) == 1
    assert len([m for _, m in said if "cloud store refused" in m]) == 1
    back = [(level, m) for level, m in said if "cloud store back" in m]
    assert len(back) == 1 and back[0][0] == logging.WARNING  # shown without -v, as its error is
    assert "stored the 1 kept messages" in back[0][1]


def test_subscribe_stopped_while_postgres_is_down_exits_2_saying_what_was_not_stored(
        outage: PgCluster, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    argv = [sys.executable, "-m", "gateway", "subscribe", "--listen", endpoint, "--key",
            "serra/farm-a/**", "--dsn", outage.dsn, "--schema", SCHEMA]
    with LineProc(argv, "serra-subscribe ready", tmp_path / "subscribe.log") as sub:
        with zenoh.open(zconfig.build("peer", connect=[endpoint])) as gw:
            pub = publisher(gw)
            pub.put(message("farm-a", "gh1", "forecast", 0).payload)
            wait_until(lambda: len(stored(outage)) == 1, what="the first message stored")
            outage.stop_server()
            pub.put(message("farm-a", "gh1", "forecast", 1).payload)
            wait_until(lambda: "cloud store refused 1 messages" in sub.text(), what="the refusal")
            pub.undeclare()
        assert sub.stop() == 2
    text = sub.text()
    assert "Traceback" not in text
    assert "subscribe stopped: received 2, stored 1," in text
    assert "error: stopped with 1 messages not stored: PostgreSQL (" in text
    assert "password" not in text

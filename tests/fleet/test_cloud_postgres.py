"""The cloud store on a real, throwaway PostgreSQL 15 cluster (tests/fleet/pg.py)."""

from __future__ import annotations

import json
import random
import re
import socket
from collections.abc import Iterator

import psycopg
import pytest

from gateway.cloud.postgres import CloudMessage, CloudStoreError, PgStore
from gateway.cloud.store import StoreConfigError
from tests.fleet.pg import PgCluster

T0 = 1_790_000_000.0  # [unix s]


def msg(i: int, farm: str = "farm-a", gh: str = "gh1", kind: str = "measurement/inside",
        t: float | None = None, payload: str | None = None, idem: str | None = None) -> CloudMessage:
    t = T0 + 60 * i if t is None else t
    return CloudMessage(key=f"serra/{farm}/{gh}/{kind}", idem=idem or f"{gh}/{kind}/{i}", farm=farm,
                        greenhouse=gh, kind=kind, t=t,
                        payload=payload or json.dumps({"i": i, "t_in": 20.0 + i / 100}),
                        received=t + 1.5)


@pytest.fixture()
def store(pg: PgCluster, request: pytest.FixtureRequest) -> Iterator[PgStore]:
    schema = "t_" + re.sub(r"[^a-z0-9_]", "_", request.node.name.lower())[:50]
    s = PgStore.connect(pg.dsn, schema=schema)
    try:
        yield s
    finally:
        s.close()
        with psycopg.connect(pg.dsn, autocommit=True) as c:
            c.execute(f"DROP SCHEMA IF EXISTS {schema} CASCADE")


def test_a_repeated_idempotency_key_is_stored_once(store: PgStore) -> None:
    assert store.insert_batch([msg(1), msg(2), msg(1)]) == 2  # a repeat inside one batch
    assert store.insert_batch([msg(2), msg(3)]) == 1  # and across batches
    assert store.insert_batch([msg(1, farm="farm-b")]) == 1  # keys are unique per farm
    assert store.count("farm-a") == 3 and store.count() == 4
    assert store.insert_batch([]) == 0


def test_a_batch_of_ten_thousand(store: PgStore) -> None:
    batch = [msg(i, gh=f"gh{i % 4}") for i in range(10_000)]
    assert store.insert_batch(batch) == 10_000
    assert store.count() == 10_000
    assert store.insert_batch(batch[::-1]) == 0  # the whole batch again: all repeats


def test_history_order_range_limit_and_filters(store: PgStore) -> None:
    rows = [msg(i) for i in range(50)] + [msg(i, kind="measurement/outside") for i in range(50)]
    rows += [msg(i, kind="forecast") for i in range(10)] + [msg(i, gh="gh2") for i in range(5)]
    random.Random(1).shuffle(rows)
    assert store.insert_batch(rows) == len(rows)
    got = store.history("farm-a", "gh1", "measurement/inside")
    assert [m.t for m in got] == [T0 + 60 * i for i in range(50)]  # oldest first
    assert json.loads(got[3].payload) == {"i": 3, "t_in": 20.03}
    assert got[3].key == "serra/farm-a/gh1/measurement/inside" and got[3].received == T0 + 181.5
    ranged = store.history("farm-a", "gh1", "measurement/inside", T0 + 600, T0 + 1200)
    assert [m.t for m in ranged] == [T0 + 60 * i for i in range(10, 21)]  # both ends included
    limited = store.history("farm-a", "gh1", "measurement/inside", T0 + 600, None, limit=3)
    assert [m.idem for m in limited] == ["gh1/measurement/inside/10", "gh1/measurement/inside/11",
                                         "gh1/measurement/inside/12"]
    both = store.history("farm-a", "gh1", "measurement/**", None, T0 + 60)
    assert sorted(m.kind for m in both) == ["measurement/inside"] * 2 + ["measurement/outside"] * 2
    assert len(store.history("farm-a", None, "measurement/inside", limit=1000)) == 55
    assert len(store.history("farm-a", limit=100_000)) == len(rows)
    assert store.history("farm-b") == []
    with pytest.raises(ValueError, match="limit 0"):
        store.history("farm-a", limit=0)


def test_latest_is_the_newest_observation_per_farm(store: PgStore) -> None:
    assert store.latest() == {}
    store.insert_batch([msg(i) for i in range(5)] + [msg(2, farm="farm-b", gh="gh9")])
    assert store.latest() == {"farm-a": T0 + 240, "farm-b": T0 + 120}  # where a catch-up starts


def test_the_schema_serves_a_cloud_engineer(store: PgStore, pg: PgCluster) -> None:
    store.insert_batch([msg(i) for i in range(5)])
    with psycopg.connect(pg.dsn) as c:
        rows = c.execute(
            f"SELECT kind, (payload->>'t_in')::float FROM {store.schema}.message "
            "WHERE farm = 'farm-a' AND greenhouse = 'gh1' AND observed >= to_timestamp(%s) "
            "ORDER BY observed", (T0 + 120,)).fetchall()
        assert rows == [("measurement/inside", 20.02), ("measurement/inside", 20.03),
                        ("measurement/inside", 20.04)]
        indexes = {r[0] for r in c.execute("SELECT indexname FROM pg_indexes WHERE schemaname = %s",
                                           (store.schema,))}
    assert {"message_series", "message_farm_time", "message_farm_idem"} <= indexes
    PgStore.connect(pg.dsn, schema=store.schema).close()  # a second subscriber: schema kept


def test_an_unstorable_message_is_left_out_and_the_rest_stored(store: PgStore) -> None:
    batch = [msg(1), msg(2, payload="{not json"), msg(3, t=float("nan")), msg(4)]
    assert store.insert_batch(batch) == 2
    assert [r.idem for r in store.rejected] == ["gh1/measurement/inside/2", "gh1/measurement/inside/3"]
    assert [m.idem for m in store.history("farm-a")] == ["gh1/measurement/inside/1",
                                                         "gh1/measurement/inside/4"]


def test_a_lost_connection_is_reopened(store: PgStore, pg: PgCluster) -> None:
    assert store.insert_batch([msg(1)]) == 1
    pid = store.conn.info.backend_pid
    with psycopg.connect(pg.dsn, autocommit=True) as admin:
        admin.execute("SELECT pg_terminate_backend(%s)", (pid,))
    assert store.insert_batch([msg(1), msg(2)]) == 1
    assert store.conn.info.backend_pid != pid and store.count() == 2


def test_a_dsn_error_is_one_clear_line_without_the_password() -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(CloudStoreError) as err:
        PgStore.connect(f"postgresql://serra:s3cret@127.0.0.1:{port}/serra", connect_timeout=5)
    text = str(err.value)
    assert "\n" not in text and "s3cret" not in text
    assert text.startswith(f"PostgreSQL (user=serra dbname=serra host=127.0.0.1 port={port}): "
                           "cannot connect:") and "Connection refused" in text
    assert not isinstance(err.value, StoreConfigError)  # a server not answering may come back
    # found without a server, no retry can help: subscribe exits 78 on these (EX_CONFIG)
    with pytest.raises(StoreConfigError, match='invalid connection option "bogus"'):
        PgStore.connect("bogus=1")
    with pytest.raises(StoreConfigError, match="schema name 'Bad-Name'"):
        PgStore.connect("host=/nonexistent", schema="Bad-Name")

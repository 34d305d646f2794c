"""Store-and-forward over real Zenoh sessions on 127.0.0.1: the outbox holds messages until a
subscriber matches their key, drains them in order, repeats are dropped by the cloud store, and
the history queryable answers from the gateway's store. Every session is closed by the test."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from gateway.cloud.store import SqliteCloudStore
from gateway.cloud.subscriber import Subscriber
from gateway.publish import zconfig
from gateway.publish.history import HistoryQueryable
from gateway.publish.publisher import OutboxPublisher
from gateway.store import Store
from gateway.store.outbox import Message, Outbox
from tests.gateway_harness import wait_for

T0 = 1_257_055_200.0
KEYS = ("serra/f1/north/forecast", "serra/f1/north/measurement/inside")


def _per_key(cloud: SqliteCloudStore) -> dict[str, list[int]]:
    return {k: [json.loads(m.payload)["n"] for m in cloud.messages() if m.key == k] for k in KEYS}


def message(i: int) -> Message:
    key = KEYS[i % 2]
    idem = f"f1/north/{key.split('north/')[1]}/{i}"
    payload = {"id": "urn:ngsi-ld:X:serra:f1:north", "type": "X", "n": i,
               "dateObserved": {"type": "Property",
                                "value": {"@type": "DateTime", "@value": _iso(T0 + 60 * i)}},
               "idempotencyKey": {"type": "Property", "value": idem}}
    return Message(key, key.split("north/")[1], T0 + 60 * i, idem, json.dumps(payload))


def _iso(t: float) -> str:
    import time

    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


@pytest.fixture
def gateway_side(tmp_path: Path) -> Iterator[tuple[Path, zenoh.Session, str]]:
    db = tmp_path / "gw.db"
    store = Store(db)
    ob = Outbox(store.conn)
    for i in range(60):
        ob.put(message(i))
    store.close()
    before = zconfig.listening_ports()
    session = zenoh.open(zconfig.build(listen=["tcp/127.0.0.1:0"]))
    try:
        (endpoint,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        yield db, session, endpoint
    finally:
        session.close()


def test_outbox_holds_until_a_subscriber_matches_then_drains_in_order(gateway_side, tmp_path) -> None:
    db, session, endpoint = gateway_side
    pub = OutboxPublisher(session, db, cache=8)
    history = HistoryQueryable(session, db, "f1")
    cloud = SqliteCloudStore(tmp_path / "cloud.db")
    sub = None
    only = None
    try:
        pub.start()
        wait_for(lambda: len(pub.state.waiting_keys) == 2, 30, "the publisher to find no subscriber")
        store = Store(db)
        assert Outbox(store.conn).pending() == 60  # nobody listens: every message held
        # a subscriber on one key only: that key drains, the other one keeps its messages
        only = zenoh.open(zconfig.build(connect=[endpoint]))
        got: list[str] = []
        s1 = only.declare_subscriber(KEYS[0], lambda s: got.append(s.payload.to_string()))
        pub.wake.set()
        wait_for(lambda: len(got) == 30, 30, "the forecast key to drain")
        assert [json.loads(x)["n"] for x in got] == list(range(0, 60, 2))
        # the publisher marks them sent after the put: the subscriber can see them first
        wait_for(lambda: Outbox(store.conn).pending() == 30, 30, "the drained key to be marked sent")
        s1.undeclare()
        only.close()
        only = None
        sub = Subscriber(cloud, [endpoint])
        sub.start()
        pub.wake.set()
        wait_for(lambda: Outbox(store.conn).pending() == 0, 30, "the outbox to drain")
        # the held key drained to it live; the forecasts that went to the first subscriber only
        # came from the gateway's history when it joined (the catch-up), all 30, not a cache's last 8
        assert sub.caught_up.wait(60), "the catch-up did not end"
        try:
            wait_for(lambda: cloud.count() >= 60, 30, "the cloud store to get every message")
        except AssertionError as e:
            raise AssertionError(f"{e}; it has {_per_key(cloud)}") from None
        assert sub.wait_idle(30)
        per_key = _per_key(cloud)
        assert per_key[KEYS[1]] == list(range(1, 60, 2))  # in order, once
        assert per_key[KEYS[0]] == list(range(0, 60, 2))
        assert sub.stats.caught_up == 60 and sub.stats.catch_up_errors == 0
        # history from the gateway's store, any subscriber state
        replies = list(session.get("serra/f1/*/history/**?from=2009-11-01T06:10:00Z;"
                                   "to=2009-11-01T06:20:00Z;limit=100",
                                   consolidation=zenoh.ConsolidationMode.NONE))
        ns = [json.loads(r.ok.payload.to_string())["n"] for r in replies]
        assert ns == list(range(10, 21))
        assert {str(r.ok.key_expr) for r in replies} == {
            "serra/f1/north/history/forecast", "serra/f1/north/history/measurement/inside"}
        few = list(session.get("serra/f1/north/history/forecast?limit=3",
                               consolidation=zenoh.ConsolidationMode.NONE))
        assert [json.loads(r.ok.payload.to_string())["n"] for r in few] == [0, 2, 4]
        # last=N: the newest N of each key (the latest of everything in one query), oldest first
        latest = list(session.get("serra/f1/*/history/**?last=2;to=2009-11-01T06:50:00Z",
                                  consolidation=zenoh.ConsolidationMode.NONE))
        assert [json.loads(r.ok.payload.to_string())["n"] for r in latest] == [47, 48, 49, 50]
        (bad,) = list(session.get("serra/f1/north/history/forecast?from=yesterday",
                                  consolidation=zenoh.ConsolidationMode.NONE))
        assert bad.err is not None and "from='yesterday'" in bad.err.payload.to_string()
        store.close()
    finally:
        if sub is not None:
            sub.stop()
        if only is not None:
            only.close()
        history.close()
        pub.stop()
        cloud.close()


def test_a_restart_puts_recent_messages_again_and_the_cloud_drops_the_repeats(
        gateway_side, tmp_path) -> None:
    db, session, endpoint = gateway_side
    cloud = SqliteCloudStore(tmp_path / "cloud.db")
    sub = Subscriber(cloud, [endpoint])
    pub = OutboxPublisher(session, db, cache=4)
    try:
        sub.start()
        pub.start()
        wait_for(lambda: cloud.count() == 60, 30, "every message in the cloud")
        pub.stop()
        # a new publisher (a restarted gateway) puts again what was sent in the last 1e9 s
        pub = OutboxPublisher(session, db, cache=4, resend_s=1e9)
        pub.start()
        assert pub.state.resent_on_start == 60
        wait_for(lambda: sub.stats.repeats >= 60, 30, "the repeats to arrive")
        assert cloud.count() == 60 and sub.stats.stored == 60
    finally:
        sub.stop()
        pub.stop()
        cloud.close()


def test_the_cloud_page_example_works_with_stock_zenoh(gateway_side) -> None:
    """docs/examples/subscribe_stock.py, as a cloud engineer would run it (stock Zenoh only)."""
    import importlib.util

    db, session, endpoint = gateway_side
    spec = importlib.util.spec_from_file_location(
        "subscribe_stock", Path(__file__).resolve().parents[1] / "docs" / "examples" / "subscribe_stock.py")
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    pub = OutboxPublisher(session, db, cache=4)
    hist = HistoryQueryable(session, db, "f1")
    lines: list[str] = []
    try:
        pub.start()
        conf = zconfig.build(connect=[endpoint])
        seen = example.main(conf, "serra/**", count=60, seconds=60,
                            history_selector="serra/f1/north/history/forecast?limit=2",
                            show=lines.append)
    finally:
        hist.close()
        pub.stop()
    assert len(seen) == 60
    assert lines[:2] == ["history X f1/north/forecast/0", "history X f1/north/forecast/2"]


def test_client_mode_through_a_router_holds_until_a_subscriber_reaches_the_router(tmp_path) -> None:
    """Gateway and cloud both in client mode, linked by a router (the Python library in router
    mode): the outbox holds until a subscriber is behind the router, then drains."""
    db = tmp_path / "gw.db"
    store = Store(db)
    for i in range(10):
        Outbox(store.conn).put(message(i))
    before = zconfig.listening_ports()
    router = zenoh.open(zconfig.build(mode="router", listen=["tcp/127.0.0.1:0"]))
    gw = cloud_s = None
    pub = None
    try:
        (ep,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        gw = zenoh.open(zconfig.build(mode="client", connect=[ep]))
        pub = OutboxPublisher(gw, db, mode="client")
        pub.start()
        wait_for(lambda: len(pub.state.waiting_keys) == 2 and pub.state.routers == 1, 30,
                 "the client gateway to see the router and nobody behind it")
        assert Outbox(store.conn).pending() == 10
        cloud_s = zenoh.open(zconfig.build(mode="client", connect=[ep]))
        got: list[int] = []
        sub = cloud_s.declare_subscriber(
            "serra/**", lambda s: got.append(json.loads(s.payload.to_string())["n"]))
        pub.wake.set()
        wait_for(lambda: len(got) == 10, 30, "the backlog through the router")
        assert sorted(got) == list(range(10))
        # the publisher marks them sent after the put: the subscriber can see them first
        wait_for(lambda: Outbox(store.conn).pending() == 0, 30, "the backlog to be marked sent")
        sub.undeclare()
    finally:
        if pub is not None:
            pub.stop()
        for s in (cloud_s, gw, router):
            if s is not None:
                s.close()
        store.close()


def test_history_answers_a_key_made_after_an_earlier_query(gateway_side) -> None:
    """The queryable reuses its list of stored keys between full listings; a key the outbox
    gained since must still be answered (a cloud's catch-up asks the moment it joins, before the
    gateway has made its first message of every kind)."""
    db, session, _ = gateway_side
    hist = HistoryQueryable(session, db, "f1")
    try:
        first = list(session.get("serra/f1/north/history/**?limit=1000",
                                 consolidation=zenoh.ConsolidationMode.NONE))
        assert len(first) == 60
        store = Store(db)
        late = Message("serra/f1/north/status", "status", T0, "f1/north/status/0",
                       json.dumps({"n": 60}))
        Outbox(store.conn).put(late)
        store.close()
        replies = list(session.get("serra/f1/north/history/status",
                                   consolidation=zenoh.ConsolidationMode.NONE))
    finally:
        hist.close()
    assert [json.loads(r.ok.payload.to_string())["n"] for r in replies] == [60]
    assert str(replies[0].ok.key_expr) == "serra/f1/north/history/status"

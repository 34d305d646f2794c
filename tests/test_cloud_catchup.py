"""The cloud subscriber's catch-up from the gateways' history (gateway/cloud/catchup.py): the
selectors it asks, where it starts, and paging over a real gateway history queryable on
127.0.0.1 (every session closed by the test)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from gateway.cloud import catchup
from gateway.cloud.store import SqliteCloudStore, parse
from gateway.publish import zconfig
from gateway.publish.history import HistoryQueryable
from gateway.store import Store
from gateway.store.outbox import Outbox
from tests.test_publish_zenoh import T0, message


def test_history_selector_under_each_kind_of_subscription() -> None:
    assert catchup.history_selector("serra/**") == "serra/*/*/history/**"
    assert catchup.history_selector("serra/farm-a/**") == "serra/farm-a/*/history/**"
    assert catchup.history_selector("serra/farm-a") == "serra/farm-a/*/history/**"
    assert catchup.history_selector("serra/f/north/measurement/inside") == \
        "serra/f/north/history/measurement/inside"
    assert catchup.history_selector("serra/f/north/**") == "serra/f/north/history/**"
    with pytest.raises(ValueError, match="not a Serra subscription"):
        catchup.history_selector("other/**")


def test_message_key_is_the_inverse_of_the_history_key() -> None:
    from gateway.publish.keyspace import history_key

    for key in ("serra/f/g/forecast", "serra/f/g/measurement/inside", "serra/f/g/device/7"):
        assert catchup.message_key(history_key(key)) == key
    with pytest.raises(ValueError, match="not a history key"):
        catchup.message_key("serra/f/g/forecast/x")


def test_it_starts_a_margin_before_the_newest_stored_observation_of_the_farm() -> None:
    latest = {"a": 10_000.0, "b": 50_000.0}
    assert catchup.since("serra/a/**", latest) == 10_000.0 - catchup.MARGIN_S
    assert catchup.since("serra/c/**", latest) is None  # nothing of farm c: everything kept
    assert catchup.since("serra/**", latest) == 10_000.0 - catchup.MARGIN_S  # no farm left out
    assert catchup.since("serra/**", {}) is None


def test_the_store_says_the_newest_observation_per_farm(tmp_path: Path) -> None:
    cloud = SqliteCloudStore(tmp_path / "c.db")
    try:
        assert cloud.latest() == {}
        cloud.add([parse(m.key, m.payload) for m in map(message, range(5))])
        assert cloud.latest() == {"f1": T0 + 60 * 4}
    finally:
        cloud.close()


@pytest.fixture
def gateway_history(tmp_path: Path) -> Iterator[str]:
    """A gateway session holding 25 messages in its store, answering history; yields its endpoint."""
    db = tmp_path / "gw.db"
    store = Store(db)
    for i in range(25):
        Outbox(store.conn).put(message(i))
    store.close()
    before = zconfig.listening_ports()
    session = zenoh.open(zconfig.build(listen=["tcp/127.0.0.1:0"]))
    history = None
    try:
        (endpoint,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        history = HistoryQueryable(session, db, "f1")
        yield endpoint
    finally:
        if history is not None:
            history.close()
        session.close()


def test_a_full_page_is_asked_again_from_its_newest_time(gateway_history, monkeypatch) -> None:
    monkeypatch.setattr(catchup, "PAGE", 10)
    got: list[tuple[str, int]] = []
    with zenoh.open(zconfig.build(connect=[gateway_history])) as s:
        stats = catchup.catch_up(s, ["serra/f1/**"], {},
                                 lambda k, p: got.append((k, json.loads(p)["n"])))
    assert stats.errors == []
    # pages t0..t9, t9..t18, t18..t24 (the boundary repeated: the store drops repeats)
    assert stats.queries == 3 and stats.replies == 27
    assert sorted({n for _, n in got}) == list(range(25))
    assert {k for k, _ in got} == {"serra/f1/north/forecast", "serra/f1/north/measurement/inside"}


def test_it_asks_only_from_shortly_before_what_the_store_holds(gateway_history, monkeypatch) -> None:
    monkeypatch.setattr(catchup, "MARGIN_S", 300.0)
    got: list[int] = []
    with zenoh.open(zconfig.build(connect=[gateway_history])) as s:
        stats = catchup.catch_up(s, ["serra/**"], {"f1": T0 + 60 * 20},
                                 lambda k, p: got.append(json.loads(p)["n"]))
    assert stats.queries == 2 and got == list(range(15, 25))  # the farms found, then f1's


def test_a_farm_new_to_the_store_gets_its_older_history_too(gateway_history, monkeypatch) -> None:
    """The store holds farm f0 up to t0 + 20 min and nothing of f1: under serra/** f1 is found
    (its gateway answers) and asked whole, f0 from its own newest time (one start for all farms
    would have left f1's first 15 messages out)."""
    monkeypatch.setattr(catchup, "MARGIN_S", 300.0)
    got: list[tuple[str, int]] = []
    with zenoh.open(zconfig.build(connect=[gateway_history])) as s:
        stats = catchup.catch_up(s, ["serra/**"], {"f0": T0 + 60 * 20},
                                 lambda k, p: got.append((k.split("/")[1], json.loads(p)["n"])))
    assert stats.errors == [] and stats.queries == 3  # the farms found, then f0, then f1
    assert sorted(n for farm, n in got if farm == "f1") == list(range(25))
    assert {farm for farm, _ in got} == {"f1"}


def test_subscriptions_over_every_farm_are_split_per_farm() -> None:
    assert catchup.per_farm("serra/**", {"b", "a"}) == ["serra/a/**", "serra/b/**"]
    assert catchup.per_farm("serra/*/north/**", ["a"]) == ["serra/a/north/**"]
    assert catchup.per_farm("serra/a/**", ["b"]) == ["serra/a/**"]  # names its farm: as itself


def test_a_cancelled_catch_up_asks_nothing(gateway_history) -> None:
    token = zenoh.CancellationToken()
    token.cancel()
    with zenoh.open(zconfig.build(connect=[gateway_history])) as s:
        stats = catchup.catch_up(s, ["serra/**"], {}, lambda k, p: None, token)
    assert stats.queries == 0 and stats.replies == 0

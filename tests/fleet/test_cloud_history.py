"""The cloud store behind one interface (SQLite, PostgreSQL): history answered from it over
real Zenoh sessions on loopback, the key-expression filter checked against Zenoh's own matching,
a refused batch kept and retried, ``subscribe --dsn`` storing into PostgreSQL."""

from __future__ import annotations

import json
import re
import threading
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.cli import main
from gateway.cloud.history import CloudHistory
from gateway.cloud.keyexpr import history_filter, regex
from gateway.cloud.postgres import PgStore
from gateway.cloud.store import CloudStore, Received, SqliteCloudStore, parse
from gateway.cloud.subscriber import Subscriber
from gateway.publish import zconfig
from gateway.publish.payloads import iso
from tests.fleet.kit import wait_until
from tests.fleet.pg import PgCluster

T0 = 1_790_000_000.0
KINDS = ("measurement/inside", "measurement/outside", "forecast", "device/7")


def message(farm: str, gh: str, kind: str, i: int) -> Received:
    idem = f"{farm}/{gh}/{kind}/{i}"
    t = T0 + 60 * i
    payload = json.dumps({"id": f"urn:x:{farm}:{gh}", "type": "X", "n": i,
                          "dateObserved": {"type": "Property", "value": {"@type": "DateTime",
                                                                         "@value": iso(t)}},
                          "idempotencyKey": {"type": "Property", "value": idem}})
    return parse(f"serra/{farm}/{gh}/{kind}", payload, received=t + 2)


def fill(store: CloudStore) -> list[Received]:
    msgs = [message(f, g, k, i) for i in range(6) for f in ("farm-a", "farm-b") for g in ("gh1", "gh2")
            for k in KINDS]
    assert store.add(msgs) == len(msgs) and store.add(msgs[:5]) == 0
    return msgs


# -- the key-expression filter ------------------------------------------------------------------
CHUNK = st.sampled_from(["serra", "farm-a", "farm-b", "gh1", "history", "measurement", "inside",
                         "x.y", "a-b"])
WILD = st.one_of(CHUNK, st.sampled_from(["*", "**", "$*a", "gh$*", "me$*t"]))


@settings(max_examples=400, deadline=None)
@given(expr=st.lists(WILD, min_size=1, max_size=6), key=st.lists(CHUNK, min_size=1, max_size=6))
def test_the_regex_matches_what_zenoh_matches(expr: list[str], key: list[str]) -> None:
    try:
        ke = zenoh.KeyExpr.autocanonize("/".join(expr))
    except zenoh.ZError:
        return  # not a key expression (e.g. "**/**" before canonisation)
    concrete = zenoh.KeyExpr("/".join(key))
    assert bool(regex(str(ke)).match("/" + str(concrete))) == ke.intersects(concrete), (ke, concrete)


def test_history_filter_pushes_the_literal_parts_down() -> None:
    f = history_filter("serra/farm-a/gh1/history/measurement/inside")
    assert (f.farm, f.greenhouse, f.kind) == ("farm-a", "gh1", "measurement/inside")
    f = history_filter("serra/farm-a/*/history/measurement/**")
    assert (f.farm, f.greenhouse, f.kind) == ("farm-a", None, "measurement/**")
    assert f.wants("serra/farm-a/gh2/measurement/outside") and not f.wants("serra/farm-a/gh2/forecast")
    f = history_filter("serra/farm-a/**")
    assert (f.farm, f.greenhouse, f.kind) == ("farm-a", None, None)
    assert f.wants("serra/farm-a/gh1/forecast")
    f = history_filter("**/history/forecast")
    assert (f.farm, f.greenhouse, f.kind) == (None, None, None)
    assert f.wants("serra/farm-b/gh1/forecast") and not f.wants("serra/farm-b/gh1/device/7")


# -- one interface, two stores ------------------------------------------------------------------
@pytest.fixture(params=["sqlite", "postgres"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[CloudStore]:
    if request.param == "sqlite":
        s: CloudStore = SqliteCloudStore(tmp_path / "cloud.db")
        yield s
        s.close()
        return
    pg: PgCluster = request.getfixturevalue("pg")
    schema = "t_history_" + re.sub(r"\W", "_", request.node.name.lower())[-30:]
    s = PgStore.connect(pg.dsn, schema=schema)
    yield s
    s.close()
    with psycopg.connect(pg.dsn, autocommit=True) as c:
        c.execute(f"DROP SCHEMA IF EXISTS {schema} CASCADE")


def test_both_stores_answer_the_same(store: CloudStore) -> None:
    msgs = fill(store)
    assert store.count() == len(msgs) and store.count("farm-a") == len(msgs) // 2
    got = store.history("farm-a", "gh1", "measurement/**", T0 + 60, T0 + 180)
    assert [(m.kind, m.idem.rsplit("/", 1)[1]) for m in got] == [
        (k, str(i)) for i in (1, 2, 3) for k in ("measurement/inside", "measurement/outside")]
    assert [m.idem for m in store.history("farm-b", None, "device/7", limit=3)] == [
        "farm-b/gh1/device/7/0", "farm-b/gh2/device/7/0", "farm-b/gh1/device/7/1"]
    only = store.history("farm-a", match=lambda key: key.endswith("/gh2/forecast"), limit=2)
    assert [m.idem for m in only] == ["farm-a/gh2/forecast/0", "farm-a/gh2/forecast/1"]
    first = next(iter(store.messages("farm-b", "gh2", "forecast")))
    assert first.idem == "farm-b/gh2/forecast/0" and json.loads(first.payload)["n"] == 0
    assert first.t == T0 and first.received == T0 + 2
    assert store.greenhouses() == [("farm-a", "gh1"), ("farm-a", "gh2"), ("farm-b", "gh1"),
                                   ("farm-b", "gh2")]
    reader = store.reader()
    try:
        assert reader.count() == len(msgs)
    finally:
        reader.close()


def test_history_is_answered_from_the_store_over_zenoh(store: CloudStore) -> None:
    fill(store)
    listen = ["tcp/127.0.0.1:0"]
    before = zconfig.listening_ports()
    with zenoh.open(zconfig.build("peer", listen=listen)) as server:
        (endpoint,) = zconfig.resolve_listen(listen, before)
        history = CloudHistory(server, store, ["farm-a", "farm-b"])
        try:
            with zenoh.open(zconfig.build("peer", connect=[endpoint])) as client:
                def ask(selector: str) -> list[zenoh.Reply]:
                    return list(client.get(selector, consolidation=zenoh.ConsolidationMode.NONE,
                                           timeout=10.0))

                wait_until(lambda: ask("serra/farm-a/gh1/history/forecast?limit=1"), what="a reply")
                replies = ask("serra/farm-a/*/history/measurement/inside?limit=3")
                assert [str(r.ok.key_expr).split("/")[2] for r in replies] == ["gh1", "gh2", "gh1"]
                assert {str(r.ok.key_expr) for r in replies} == {
                    "serra/farm-a/gh1/history/measurement/inside",
                    "serra/farm-a/gh2/history/measurement/inside"}
                assert [json.loads(r.ok.payload.to_string())["n"] for r in replies] == [0, 0, 1]
                # ?last=N as a gateway answers it (what `status --connect` asks): per key
                latest = ask("serra/farm-a/*/history/**?last=1")
                assert len(latest) == 2 * len(KINDS)  # greenhouses x kinds, once each
                assert {json.loads(r.ok.payload.to_string())["n"] for r in latest} == {5}
                two = ask("serra/farm-a/gh1/history/forecast?last=2")
                assert [json.loads(r.ok.payload.to_string())["n"] for r in two] == [4, 5]
                capped = ask("serra/farm-b/gh2/history/**?last=2;limit=3")
                assert [json.loads(r.ok.payload.to_string())["n"] for r in capped] == [5, 5, 5]
                both = ask(f"serra/*/gh2/history/device/7?from={iso(T0 + 120)};to={iso(T0 + 180)}")
                assert sorted(str(r.ok.key_expr) for r in both) == [
                    "serra/farm-a/gh2/history/device/7"] * 2 + ["serra/farm-b/gh2/history/device/7"] * 2
                (bad,) = ask("serra/farm-a/gh1/history/forecast?from=yesterday")
                assert bad.err is not None and "from" in bad.err.payload.to_string()
        finally:
            history.close()
    assert history.answered >= 3


class RefusingStore:
    """A real SQLite store that refuses its first `n` batches (a database that is down)."""

    def __init__(self, inner: SqliteCloudStore, n: int) -> None:
        self.inner, self.n, self.refused = inner, n, 0
        self.lock = threading.Lock()

    def add(self, messages):
        with self.lock:
            if self.refused < self.n:
                self.refused += 1
                raise RuntimeError("PostgreSQL (host=db): connection refused")
        return self.inner.add(messages)

    def __getattr__(self, name: str):
        return getattr(self.inner, name)


def test_a_batch_the_store_refuses_is_kept_and_stored_later(tmp_path: Path) -> None:
    inner = SqliteCloudStore(tmp_path / "cloud.db")
    store = RefusingStore(inner, 2)
    listen = ["tcp/127.0.0.1:0"]
    before = zconfig.listening_ports()
    sub = Subscriber(store, listen=listen, keys=["serra/farm-a/**"])  # type: ignore[arg-type]
    try:
        sub.start()
        (endpoint,) = zconfig.resolve_listen(listen, before)
        with zenoh.open(zconfig.build("peer", connect=[endpoint])) as gw:
            pub = gw.declare_publisher("serra/farm-a/gh1/forecast",
                                       congestion_control=zenoh.CongestionControl.BLOCK)
            wait_until(lambda: pub.matching_status.matching, what="the subscriber")
            for i in range(5):
                pub.put(message("farm-a", "gh1", "forecast", i).payload)
            wait_until(lambda: inner.count() == 5, what="the kept batch stored after the refusals")
            pub.undeclare()
    finally:
        sub.stop()
    assert store.refused == 2 and sub.stats.store_retries == 2 and sub.error is None
    assert [m.idem for m in inner.messages()] == [f"farm-a/gh1/forecast/{i}" for i in range(5)]
    inner.close()


def test_subscribe_dsn_stores_into_postgres_and_exports(pg: PgCluster, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    schema = "t_subscribe_cli"
    store = PgStore.connect(pg.dsn, schema=schema)
    try:
        fill(store)
        assert main(["subscribe", "--dsn", pg.dsn, "--schema", schema, "--export",
                     str(tmp_path / "csv")]) == 0
        out = capsys.readouterr().out
        assert "no measurement" not in out and len(list((tmp_path / "csv").glob("*.csv"))) == 4
        assert main(["subscribe", "--dsn", "host=/nonexistent port=1", "--export", "x"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: PostgreSQL (host=/nonexistent port=1): cannot connect:")
    finally:
        store.close()
        with psycopg.connect(pg.dsn, autocommit=True) as c:
            c.execute(f"DROP SCHEMA IF EXISTS {schema} CASCADE")

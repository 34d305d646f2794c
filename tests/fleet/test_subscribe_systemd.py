"""``python -m gateway subscribe`` under systemd (images/gateway/cloud/serra-subscribe.service,
Type=notify): the real process with ``$NOTIFY_SOCKET`` naming a socket this test binds, as
systemd would. READY=1 comes after the ready line, STATUS= counts what was stored, STOPPING=1 at
SIGTERM before exit 0; a wrong setting exits 78 (EX_CONFIG, not restarted) having sent nothing,
and a PostgreSQL that does not answer at start exits 2 (restarted), also before READY=1."""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest
import zenoh

from gateway.publish import zconfig
from tests.fleet.kit import free_port
from tests.fleet.pg import PgCluster
from tests.fleet.test_cloud_history import message
from tests.fleet.test_cloud_outage import publisher
from tests.test_sdnotify import DEADLINE, service, stdout_so_far, stop_cleanly

SCHEMA = "t_systemd"


def subscriber_toml(tmp_path: Path, subscribe: str, tables: str = "") -> Path:
    path = tmp_path / "subscriber.toml"
    path.write_text(f"[subscribe]\n{subscribe}\n{tables}")
    return path


def subscribe_argv(config: Path) -> list[str]:
    return [sys.executable, "-m", "gateway", "subscribe", "--config", str(config)]


@pytest.fixture()
def schema(pg: PgCluster) -> Iterator[PgCluster]:
    """The session's cluster; this test's schema dropped after."""
    yield pg
    with psycopg.connect(pg.dsn, autocommit=True) as c:
        c.execute(f"DROP SCHEMA IF EXISTS {SCHEMA} CASCADE")


def test_subscribe_is_ready_after_its_line_counts_what_it_stores_and_says_stopping(
        schema: PgCluster, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = subscriber_toml(tmp_path, f'listen = ["{endpoint}"]\nkeys = ["serra/farm-a/**"]\n'
                             f'dsn = "{schema.dsn}"\nschema = "{SCHEMA}"')
    with service(subscribe_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        ready, before = sock.wait_for("READY", proc)
        assert not before and ready["READY"] == "1", (before, ready)
        assert ready["STATUS"].startswith("0 messages stored, 0 held; zenoh "), ready
        line = stdout_so_far(proc)  # printed before READY=1 was sent
        assert line.startswith(f"serra-subscribe ready serra/farm-a/** on {endpoint} store "), line
        with zenoh.open(zconfig.build("peer", connect=[endpoint])) as gw:
            pub = publisher(gw)  # once the subscription is known: a put before it is dropped
            pub.put(message("farm-a", "gh1", "forecast", 0).payload)
            while "1 message stored" not in (status := sock.wait_for("STATUS", proc)[0]["STATUS"]):
                pass  # each STATUS= differs from the last; the count reaches 1 or wait_for fails
            assert status.startswith("1 message stored, 0 held; zenoh linked (0 routers, 1 peer)"), \
                status
            pub.undeclare()
        stop_cleanly(proc, sock)  # STOPPING=1 + STATUS=stopping, then exit 0
    with psycopg.connect(schema.dsn) as c:
        assert c.execute(f"SELECT idem FROM {SCHEMA}.message").fetchall() == [
            ("farm-a/gh1/forecast/0",)]


@pytest.mark.parametrize(("subscribe", "tables", "said"), [
    ('listen = ["tcp/127.0.0.1:7447"]\ndb = "c.db"\nbogus = 1', "", "bogus"),
    ('listen = ["tcp/127.0.0.1:7447"]\ndsn = "host=/nowhere port"', "",
     'error: PostgreSQL DSN: missing "=" after "port"'),
    ('mode = "client"\nconnect = ["tls/127.0.0.1:7447"]\ndb = "c.db"',
     '[tls]\nca = "missing-ca.pem"\n', "missing-ca.pem"),
    ('mode = "client"\ndb = "c.db"', "", "client mode needs a router in connect"),
])
def test_subscribe_with_a_wrong_setting_exits_78_and_never_says_ready(
        tmp_path: Path, subscribe: str, tables: str, said: str) -> None:
    config = subscriber_toml(tmp_path, subscribe, tables)
    with service(subscribe_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        assert proc.wait(timeout=DEADLINE) == os.EX_CONFIG == 78
        assert sock.next(0) == {}  # a datagram sent before the exit would be queued by now
    err = (tmp_path / "service.stderr").read_text().strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and said in err[0], err
    assert not (tmp_path / "c.db").exists()


def test_subscribe_whose_postgresql_does_not_answer_at_start_exits_2_and_never_says_ready(
        tmp_path: Path) -> None:
    """A server not up yet (or not provisioned yet) may answer at the next start: exit 2, which
    the unit restarts, not 78."""
    config = subscriber_toml(tmp_path, f'listen = ["tcp/127.0.0.1:{free_port()}"]\n'
                             f'dsn = "host={tmp_path} dbname=serra user=serra"')
    with service(subscribe_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        assert proc.wait(timeout=DEADLINE) == 2
        assert sock.next(0) == {}
    err = (tmp_path / "service.stderr").read_text().strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: PostgreSQL (") and "cannot connect" in err[0]


def test_subscribe_refused_by_its_postgresql_at_start_exits_2_not_78(pg: PgCluster,
                                                                      tmp_path: Path) -> None:
    """The server answers but refuses (here: no such database; a wrong password or a missing
    role alike): decided by the server and fixed there, maybe by a provisioning run after this
    start, so exit 2, restarted, not 78 (docs/cloud.md, "Under systemd")."""
    dsn = pg.dsn.replace("dbname=postgres", "dbname=not_provisioned_yet")
    config = subscriber_toml(tmp_path, f'listen = ["tcp/127.0.0.1:{free_port()}"]\ndsn = "{dsn}"')
    with service(subscribe_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        assert proc.wait(timeout=DEADLINE) == 2
        assert sock.next(0) == {}
    err = (tmp_path / "service.stderr").read_text().strip().splitlines()
    assert len(err) == 1 and 'database "not_provisioned_yet" does not exist' in err[0], err


def test_subscribe_waiting_for_its_router_says_so_and_is_not_ready(tmp_path: Path) -> None:
    """Client mode with no router answering: no READY=1 (systemctl start waits, up to the unit's
    TimeoutStartSec=), but STATUS= says what it waits for; SIGTERM meanwhile exits 0."""
    port = free_port()
    config = subscriber_toml(tmp_path, f'mode = "client"\nconnect = ["tcp/127.0.0.1:{port}"]\n'
                             'db = "cloud.db"')
    with service(subscribe_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        status, before = sock.wait_for("STATUS", proc)
        assert not before and "READY" not in status, (before, status)
        assert status["STATUS"].startswith(
            f"0 messages stored, 0 held; zenoh connecting to tcp/127.0.0.1:{port} (attempt "), status
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=DEADLINE) == 0
        assert not [m for m in iter(lambda: sock.next(0), {}) if "READY" in m]
        assert "serra-subscribe ready" not in stdout_so_far(proc)

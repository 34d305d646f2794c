"""The tools that only connect out, and a gateway given no ``listen``, open no listening socket
(``zconfig.build(dial_only=True)``): Zenoh's peer default would listen on every interface at a
random port."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from gateway.cloud.store import SqliteCloudStore
from gateway.cloud.subscriber import Subscriber
from gateway.publish import zconfig
from gateway.status.zenoh_source import ZenohSource
from tests.gateway_harness import GatewayProcess, wait_for, write_config


@pytest.fixture
def far_side() -> Iterator[tuple[zenoh.Session, str]]:
    """A peer listening on loopback (the gateway, or the cloud's subscriber)."""
    before = zconfig.listening_ports()
    session = zenoh.open(zconfig.build(listen=["tcp/127.0.0.1:0"]))
    try:
        (endpoint,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        yield session, endpoint
    finally:
        session.close()


def _connected(session: zenoh.Session) -> bool:
    return bool(list(session.info.peers_zid()))


def test_a_peer_that_only_dials_opens_no_port(far_side):
    session, endpoint = far_side
    ports = zconfig.listening_ports()
    quiet = zenoh.open(zconfig.build(connect=[endpoint], dial_only=True))
    try:
        wait_for(lambda: _connected(session), 30, "the dialling peer to connect")
        assert zconfig.listening_ports() == ports
    finally:
        quiet.close()
    # without it, Zenoh's default: a new listener, on every interface
    loud = zenoh.open(zconfig.build(connect=[endpoint]))
    try:
        assert len(zconfig.listening_ports()) == len(ports) + 1
    finally:
        loud.close()


def test_the_status_screen_over_zenoh_opens_no_port(far_side):
    session, endpoint = far_side
    ports = zconfig.listening_ports()
    source = ZenohSource([endpoint])
    try:
        wait_for(lambda: _connected(session), 30, "the screen's session to connect")
        assert zconfig.listening_ports() == ports
    finally:
        source.close()


def test_a_subscriber_given_connect_alone_opens_no_port(far_side, tmp_path: Path):
    session, endpoint = far_side
    ports = zconfig.listening_ports()
    cloud = SqliteCloudStore(tmp_path / "cloud.db")
    sub = Subscriber(cloud, [endpoint])
    try:
        sub.start()
        wait_for(lambda: _connected(session), 30, "the subscriber to connect")
        assert zconfig.listening_ports() == ports
    finally:
        sub.stop()
        cloud.close()


def test_a_gateway_given_connect_alone_opens_no_port(far_side, tmp_path: Path):
    """The gateway service in peer mode with ``connect`` and no ``listen``: it dials the far
    side and listens on nothing (its kits come over UDP)."""
    session, endpoint = far_side
    gw = GatewayProcess(write_config(tmp_path, anchor=time.time(), zenoh_listen=None,
                                     zenoh_connect=endpoint))
    gw.start()
    try:
        assert gw.proc is not None
        wait_for(lambda: _connected(session), 60, "the gateway to connect")
        assert zconfig.listening_ports(gw.proc.pid) == []
    finally:
        gw.stop()


def test_a_gateway_given_neither_listen_nor_connect_listens_nowhere_and_says_so(tmp_path: Path):
    """A peer given no endpoint at all: Zenoh's default would listen on every interface at a
    random port ([::]:PORT, measured), a door on the farm's network that the config never asked
    for and no subscriber could find. It listens nowhere, and its log says how to set one."""
    gw = GatewayProcess(write_config(tmp_path, anchor=time.time(), zenoh_listen=None))
    gw.start()
    try:
        assert gw.proc is not None
        assert gw.zenoh == "-"  # the ready line: no endpoint
        assert zconfig.listening_ports(gw.proc.pid) == []
    finally:
        assert gw.stop() == 0
    log = (tmp_path / "gateway.log").read_text()
    assert "listens nowhere" in log and "set [zenoh] listen" in log, log

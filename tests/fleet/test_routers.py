"""Routers in a chain on loopback (each ``python -m gateway router`` in its own process):
gateway (client) → regional router → cloud router → store, with mutual TLS and access control
on every link. A gateway fails over between two regional routers and comes back; a regional
router started before its upstream links up when the upstream appears."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from contextlib import ExitStack
from pathlib import Path

import zenoh

from gateway.net.acl import AccessSpec, Subscriber
from tests.fleet.conftest import ACCESS
from tests.fleet.kit import (
    ROOT,
    Inbox,
    Pki,
    RouterProc,
    open_client,
    signal_and_wait,
    wait_until,
    write_router_toml,
)

BLOCK = zenoh.CongestionControl.BLOCK
SPEC = AccessSpec(gateways=tuple(ACCESS["gateways"]), routers=tuple(ACCESS["routers"]),
                  subscribers=(Subscriber("store", ("*",), True),))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _subscribe_store(store: zenoh.Session, inbox: Inbox) -> None:
    for key in SPEC.subscriptions("store"):  # one per farm: the gateways see them
        store.declare_subscriber(key, inbox)


def _on(session: zenoh.Session, router: RouterProc) -> bool:
    return [str(z) for z in session.info.routers_zid()] == [router.zid]


def test_a_gateway_fails_over_between_two_routers_and_back(pki: Pki, tmp_path: Path) -> None:
    with ExitStack() as stack:
        cloud = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "cloud.toml", "cloud", pki, access=ACCESS)))
        regions = [stack.enter_context(RouterProc(write_router_toml(
            tmp_path / f"{name}.toml", name, pki, connect=cloud.endpoints, access=ACCESS)))
            for name in ("region-1", "region-2")]
        store = stack.enter_context(open_client(pki, "store", cloud.endpoints))
        inbox = Inbox()
        _subscribe_store(store, inbox)
        # the gateway's connect list holds both regional routers; it uses one at a time
        gw = stack.enter_context(open_client(pki, "farm-a", [r.endpoints[0] for r in regions]))
        pub = gw.declare_publisher("serra/farm-a/gh1/measurement/inside", congestion_control=BLOCK)

        def send(tag: str) -> None:  # what an outbox does: wait for a listener, put, confirm
            wait_until(lambda: pub.matching_status.matching, what=f"a listener before {tag}")
            pub.put(tag)
            wait_until(lambda: inbox.has(tag), what=f"{tag} at the cloud store")

        send("m1")
        first = wait_until(lambda: next((r for r in regions if _on(gw, r)), None), what="a link")
        other = regions[1] if first is regions[0] else regions[0]
        port = first.port
        first.kill()  # a crash: nothing closed cleanly
        wait_until(lambda: _on(gw, other), what="the gateway on the other router")
        send("m2")
        # the crashed router comes back on its port; the other one is stopped (SIGTERM)
        back = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "back.toml", first.config.stem, pki, listen=[f"tls/127.0.0.1:{port}"],
            connect=cloud.endpoints, access=ACCESS)))
        assert other.stop() == 0
        wait_until(lambda: _on(gw, back), what="the gateway back on the restarted router")
        send("m3")
        assert inbox.payloads() == ["m1", "m2", "m3"]


def test_a_router_links_to_its_upstream_when_it_appears(pki: Pki, tmp_path: Path) -> None:
    cloud_port = _free_port()  # nothing listens there yet
    cloud_ep = f"tls/127.0.0.1:{cloud_port}"
    with ExitStack() as stack:
        region = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "region-1.toml", "region-1", pki, connect=[cloud_ep], access=ACCESS)))
        gw = stack.enter_context(open_client(pki, "farm-b", region.endpoints))
        pub = gw.declare_publisher("serra/farm-b/gh2/status", congestion_control=BLOCK)
        assert not pub.matching_status.matching  # no cloud yet: nobody listens
        cloud = stack.enter_context(RouterProc(write_router_toml(
            tmp_path / "cloud.toml", "cloud", pki, listen=[cloud_ep], access=ACCESS)))
        store = stack.enter_context(open_client(pki, "store", cloud.endpoints))
        inbox = Inbox()
        _subscribe_store(store, inbox)
        wait_until(lambda: pub.matching_status.matching, what="the store, through two routers")

        # Matching can turn true while the new link's routes still settle, and a plain put sent
        # then may be dropped (it failed so once under load; the gateway's advanced publisher
        # recovers such a sample, this plain one does not): put until one arrives.
        def arrived() -> bool:
            pub.put("up")
            return inbox.has("up")

        wait_until(arrived, what="a put at the cloud store", interval=0.2)
        assert set(inbox.items) == {("serra/farm-b/gh2/status", "up")}


def test_the_router_log_has_no_colour_codes_off_a_terminal(pki: Pki, tmp_path: Path) -> None:
    """Under systemd (or `> file`) Zenoh's log is read with journalctl and grep: the refusal lines
    docs/fleet.md quotes must be plain text, not wrapped in ANSI colour codes."""
    env = {k: v for k, v in os.environ.items() if k != "NO_COLOR"}
    out = tmp_path / "router.out"
    with open(out, "w", encoding="utf-8") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "gateway", "router", "--config",
             str(write_router_toml(tmp_path / "cloud.toml", "cloud", pki, log="info"))],
            cwd=ROOT, stdout=f, stderr=subprocess.STDOUT, env=env)
    try:
        wait_until(lambda: "serra router ready" in out.read_text(), what="the router ready")
    finally:
        signal_and_wait(proc, signal.SIGTERM, 60, "the router")
    text = out.read_text()
    assert "zenoh::net::runtime" in text  # Zenoh's own INFO lines are there ...
    assert "\x1b[" not in text  # ... without colour codes

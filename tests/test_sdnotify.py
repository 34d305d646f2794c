"""systemd's readiness protocol (the units are Type=notify): the real gateway, ingest and router
processes with ``$NOTIFY_SOCKET`` naming a unix datagram socket this test binds, as systemd
would. READY=1 comes once the ready line's conditions hold (the UDP port acknowledges a record,
the Zenoh port accepts a connection), STOPPING=1 at SIGTERM before a clean exit, and a wrong
config exits 78 having sent nothing. gateway/sdnotify.py itself at the end."""

from __future__ import annotations

import os
import re
import secrets
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from gateway import protocol
from gateway.sdnotify import Notifier, socket_address
from gateway.store.keys import write_keys
from tests.gateway_harness import KEY, write_config

DEADLINE = 120.0  # [s] for a start or a stop on a loaded machine


class NotifySocket:
    """What systemd listens on: a unix datagram socket (a path, or an abstract ``@name``)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        address = socket_address(name)
        assert address is not None
        self.sock.bind(address)

    def next(self, timeout: float = DEADLINE) -> dict[str, str]:
        """The next datagram's fields ({} when none came within ``timeout``)."""
        if not select.select([self.sock], [], [], timeout)[0]:
            return {}
        lines = self.sock.recv(4096).decode().splitlines()
        return dict(line.partition("=")[::2] for line in lines)

    def wait_for(self, key: str, proc: subprocess.Popen) -> tuple[dict[str, str], list[dict]]:
        """The first datagram holding ``key`` and the ones before it."""
        before: list[dict] = []
        end = time.monotonic() + DEADLINE
        while (left := end - time.monotonic()) > 0:
            exited = proc.poll() is not None  # before the read: what it sent is queued by then
            msg = self.next(0 if exited else min(left, 1.0))
            if key in msg:
                return msg, before
            if msg:
                before.append(msg)
            elif exited:
                break
        raise AssertionError(f"no {key} from the service (exit {proc.poll()}); before: {before}")

    def close(self) -> None:
        self.sock.close()
        if not self.name.startswith("@"):
            os.unlink(self.name)


@contextmanager
def service(argv: list[str], cwd: Path, notify: str,
            **env: str) -> Iterator[tuple[subprocess.Popen, NotifySocket]]:
    """A service process told to notify ``notify``; killed if the test left it running (its
    temporary folders in ``cwd``: a killed gateway leaves its work folder)."""
    sock = NotifySocket(notify)
    with (cwd / "service.stderr").open("w") as err:
        proc = subprocess.Popen(argv, cwd=cwd, stdout=subprocess.PIPE, stderr=err,
                                env={**os.environ, "NOTIFY_SOCKET": notify, "TMPDIR": str(cwd),
                                     **env})
    try:
        yield proc, sock
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=60)
        sock.close()


def stdout_so_far(proc: subprocess.Popen) -> str:
    """What the service printed up to now, without waiting for more."""
    assert proc.stdout is not None
    fd, out = proc.stdout.fileno(), b""
    while select.select([fd], [], [], 0)[0]:
        chunk = os.read(fd, 65536)
        if not chunk:
            break
        out += chunk
    return out.decode()


def stop_cleanly(proc: subprocess.Popen, sock: NotifySocket) -> None:
    proc.send_signal(signal.SIGTERM)
    msg, _ = sock.wait_for("STOPPING", proc)
    assert msg["STOPPING"] == "1" and msg["STATUS"] == "stopping", msg
    assert proc.wait(timeout=DEADLINE) == 0


def udp_status(status: str) -> tuple[str, int]:
    """``udp HOST:PORT`` in a STATUS= line."""
    words = status.replace(",", " ").replace(";", " ").split()
    host, port = words[words.index("udp") + 1].rsplit(":", 1)
    return host, int(port)


def acknowledged(address: tuple[str, int], key: bytes) -> bool:
    """Kit 7's first record sent to ``address`` comes back acknowledged as stored."""
    rec = protocol.Record(7, 0, 0, 60_000, 0, 60.0, (21.5, 60.0, 15.0, 70.0, 300.0, 2.0, 0),
                          (0,) * 7)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(DEADLINE)
        s.sendto(protocol.encode_record(rec, key), address)
        ack = protocol.decode_ack(s.recv(64), key)
    return (ack.device_id, ack.seq, ack.status) == (7, 0, protocol.ACK_STORED)


def accepts_tcp(port: int) -> bool:
    with socket.create_connection(("127.0.0.1", port), timeout=DEADLINE):
        return True


def gateway_argv(config: Path) -> list[str]:
    return [sys.executable, "-m", "gateway", "run", "--config", str(config)]


def test_gateway_is_ready_once_it_serves_and_says_stopping_at_sigterm(tmp_path: Path) -> None:
    config = write_config(tmp_path, anchor=time.time())
    with service(gateway_argv(config), tmp_path, str(tmp_path / "notify"),
                 WATCHDOG_USEC="3000000") as (proc, sock):
        ready, before = sock.wait_for("READY", proc)
        assert not before and ready["READY"] == "1", (before, ready)  # nothing before it
        # the ready line was printed first; the UDP port, the store and Zenoh's port all serve
        line = next(ln for ln in stdout_so_far(proc).splitlines() if ln.startswith("serra-gateway"))
        assert line.startswith("serra-gateway ready udp 127.0.0.1:"), line
        status = ready["STATUS"]
        assert status.startswith("1 greenhouse, 1 kit; udp 127.0.0.1:"), status
        assert status.endswith("; zenoh open, not linked yet"), status
        assert f"udp {udp_status(status)[0]}:{udp_status(status)[1]}" in line
        assert acknowledged(udp_status(status), KEY)
        zenoh = line.split()[line.split().index("zenoh") + 1]
        assert zenoh.startswith("tcp/127.0.0.1:") and accepts_tcp(int(zenoh.rsplit(":", 1)[1]))
        # WatchdogSec= set: the supervising loop pings (every second, well within 3 s)
        ping, _ = sock.wait_for("WATCHDOG", proc)
        assert ping == {"WATCHDOG": "1"}
        stop_cleanly(proc, sock)
        assert not [m for m in iter(lambda: sock.next(0), {}) if "READY" in m or "WATCHDOG" in m]


def test_gateway_without_its_router_is_ready_and_says_it_is_connecting(tmp_path: Path) -> None:
    """A client whose router does not answer (a missing cloud, a router not up yet) serves the
    kits anyway: READY=1, and STATUS= says Zenoh is still connecting (``systemctl start``
    neither hangs nor fails on it)."""
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = write_config(tmp_path, anchor=time.time(), zenoh_listen=None,
                          zenoh_connect=f"tcp/127.0.0.1:{port}")
    config.write_text(config.read_text().replace("[zenoh]\n", '[zenoh]\nmode = "client"\n', 1))
    with service(gateway_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        ready, _ = sock.wait_for("READY", proc)
        # attempt 1 at start; a loaded machine may reach READY=1 after the first retry (0.5 s)
        said = re.search(rf"; zenoh connecting to tcp/127\.0\.0\.1:{port} \(attempt \d+\)$",
                         ready["STATUS"])
        assert said, ready
        assert acknowledged(udp_status(ready["STATUS"]), KEY)
        stop_cleanly(proc, sock)


def test_gateway_with_a_wrong_config_exits_78_and_never_says_ready(tmp_path: Path) -> None:
    config = write_config(tmp_path, anchor=time.time())
    config.write_text(config.read_text().replace("[gateway]\n", "[gateway]\nfarmm = 'x'\n", 1))
    with service(gateway_argv(config), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        assert proc.wait(timeout=DEADLINE) == os.EX_CONFIG == 78
        assert sock.next(0) == {}  # a datagram sent before the exit would be queued by now
    assert "gateway.farmm: unknown key" in (tmp_path / "service.stderr").read_text()


def ingest_argv(tmp_path: Path) -> list[str]:
    return [sys.executable, "-m", "gateway.ingest.service", "--db", str(tmp_path / "serra.db"),
            "--keys", str(tmp_path / "keys.txt"), "--listen", "127.0.0.1:0"]


def test_ingest_is_ready_once_its_port_acknowledges_on_an_abstract_socket(tmp_path: Path) -> None:
    key = secrets.token_bytes(32)
    write_keys(tmp_path / "keys.txt", {7: key})
    name = f"@serra-test-{secrets.token_hex(8)}"  # systemd's own form: an abstract name
    with service(ingest_argv(tmp_path), tmp_path, name) as (proc, sock):
        ready, before = sock.wait_for("READY", proc)
        assert not before and ready["STATUS"].startswith("udp 127.0.0.1:"), (before, ready)
        assert f"serra-ingest listening {ready['STATUS']}" in stdout_so_far(proc)
        assert acknowledged(udp_status(ready["STATUS"]), key)
        stop_cleanly(proc, sock)


def test_ingest_without_its_keys_file_exits_78_and_never_says_ready(tmp_path: Path) -> None:
    with service(ingest_argv(tmp_path), tmp_path, str(tmp_path / "notify")) as (proc, sock):
        assert proc.wait(timeout=DEADLINE) == os.EX_CONFIG
        assert sock.next(0) == {}
    assert not (tmp_path / "serra.db").exists()


def router_config(tmp_path: Path, listen: str) -> Path:
    path = tmp_path / "router.toml"
    path.write_text(f'[router]\nname = "r1"\nlisten = ["{listen}"]\n')
    return path


def test_router_is_ready_once_its_port_accepts_and_says_stopping(tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = [sys.executable, "-m", "gateway", "router", "--config",
            str(router_config(tmp_path, f"tcp/127.0.0.1:{port}"))]
    with service(argv, tmp_path, str(tmp_path / "notify")) as (proc, sock):
        ready, before = sock.wait_for("READY", proc)
        assert not before and ready["STATUS"] == f"listening tcp/127.0.0.1:{port}", ready
        assert "serra router ready:" in stdout_so_far(proc)
        assert accepts_tcp(port)
        stop_cleanly(proc, sock)


def test_router_with_a_wrong_config_exits_78_and_never_says_ready(tmp_path: Path) -> None:
    argv = [sys.executable, "-m", "gateway", "router", "--config",
            str(router_config(tmp_path, "tcp/127.0.0.1:99999"))]
    with service(argv, tmp_path, str(tmp_path / "notify")) as (proc, sock):
        assert proc.wait(timeout=DEADLINE) == os.EX_CONFIG
        assert sock.next(0) == {}


def test_notifier_does_nothing_without_notify_socket_and_speaks_both_address_forms(
        tmp_path: Path) -> None:
    quiet = Notifier({})
    assert not quiet.enabled and not quiet.send("READY=1")
    assert socket_address("/run/systemd/notify") == "/run/systemd/notify"
    assert socket_address("@/org/freedesktop/systemd1/notify") == b"\0/org/freedesktop/systemd1/notify"
    assert socket_address("vsock:2:1234") is None and socket_address("@") is None
    sock = NotifySocket(str(tmp_path / "n"))
    try:
        n = Notifier({"NOTIFY_SOCKET": sock.name, "WATCHDOG_USEC": "1000000",
                      "WATCHDOG_PID": str(os.getpid() + 1)})  # the watchdog is another's
        n.watchdog()
        n.status("before ready")  # nothing before READY=1, nor STOPPING=1
        n.stopping()
        n.ready("a\nb")
        assert sock.next(5) == {"READY": "1", "STATUS": "a b"}  # one line: newlines flattened
        n.watchdog()
        n.status("a b")  # unchanged: not sent again
        n.status("c")
        assert sock.next(5) == {"STATUS": "c"}
        n.stopping()
        n.stopping()
        n.status("d")
        assert sock.next(5) == {"STOPPING": "1", "STATUS": "stopping"} and sock.next(0) == {}
    finally:
        sock.close()
    gone = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody")})  # logged once, not raised
    gone.ready("x")
    assert gone.readied and not gone.send("STATUS=y")


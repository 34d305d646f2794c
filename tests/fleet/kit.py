"""Test kit for Zenoh fleets on loopback: certificates, routers in subprocesses, clients, waits.

Reused by the security, failover and fleet tests::

    pki = make_pki(tmp, routers=["r1"], gateways=["farm-a"], clients=["store"])
    with RouterProc(write_router_toml(tmp / "r1.toml", "r1", pki, access=...)) as r1:
        with open_client(pki, "farm-a", r1.endpoints) as session: ...

Every router runs as ``python -m gateway router`` (the real command), listens on port 0 and
reports its bound endpoint on its ``ready`` line; its stderr (Zenoh's log) goes to a file that
tests read. Nothing here sleeps to synchronise: :func:`wait_until` polls a condition.
"""

from __future__ import annotations

import datetime as dt
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from gateway.net.certs import Issued, issue, make_ca
from gateway.net.router import READY
from gateway.net.zenohcfg import Retry, TlsFiles, build, client_entries

ROOT = Path(__file__).resolve().parents[2]
DEADLINE = 60.0
ANSI = re.compile(r"\x1b\[[0-9;]*m")  # generous: 2 cores shared by several test runs


def wait_until(cond: Callable[[], Any], timeout: float = DEADLINE, what: str = "condition",
               interval: float = 0.02) -> Any:
    """Poll `cond` until it returns a true value (returned) or fail after `timeout` seconds."""
    end = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(interval)


def stays_false(cond: Callable[[], Any], duration: float) -> bool:
    """True if `cond` stays false for `duration` seconds (a bounded wait for nothing to happen,
    used only after a positive control has shown that the path works)."""
    end = time.monotonic() + duration
    while time.monotonic() < end:
        if cond():
            return False
        time.sleep(0.02)
    return not cond()


def pump_lines(proc: subprocess.Popen[str], log_path: Path, lines: list[str]) -> None:
    """A child's output, line by line without colour codes, into ``lines`` and its log file
    (run on a reader thread until the child closes its output)."""
    assert proc.stdout is not None
    with open(log_path, "a", encoding="utf-8") as log:
        for line in proc.stdout:
            line = ANSI.sub("", line.rstrip("\n"))
            lines.append(line)
            log.write(line + "\n")
            log.flush()


def signal_and_wait(proc: subprocess.Popen[str], sig: int, timeout: float, what: str) -> None:
    """Send ``sig`` to a running child and wait: it must exit by itself (a hang is killed and
    is a failure)."""
    if proc.poll() is not None:
        return
    proc.send_signal(sig)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"{what} did not stop on signal {sig}") from None


@dataclass
class Pki:
    """A fleet CA in a folder and the certificates issued by it, by common name."""

    folder: Path
    ca: Issued
    issued: dict[str, Issued] = field(default_factory=dict)

    def tls(self, name: str, mutual: bool = True) -> TlsFiles:
        i = self.issued[name]
        return TlsFiles(ca=self.ca.cert, cert=i.cert, key=i.key, mutual=mutual)

    def add(self, role: str, name: str, **kw: Any) -> Issued:
        self.issued[name] = issue(self.ca, role, name, self.folder, **kw)
        return self.issued[name]

    def add_expired(self, name: str) -> Issued:
        start = dt.datetime.now(dt.UTC) - dt.timedelta(days=30)
        return self.add("gateway", name, not_before=start, days=1)


def make_pki(folder: Path, routers: Iterable[str] = (), gateways: Iterable[str] = (),
             clients: Iterable[str] = ()) -> Pki:
    folder.mkdir(parents=True, exist_ok=True)
    pki = Pki(folder, make_ca(folder))
    for name in routers:
        pki.add("router", name)
    for name in gateways:
        pki.add("gateway", name)
    for name in clients:
        pki.add("client", name)
    return pki


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def write_router_toml(path: Path, name: str, pki: Pki, *, listen: Iterable[str] = ("tls/127.0.0.1:0",),
                      connect: Iterable[str] = (), access: dict[str, Any] | None = None,
                      log: str = "warn", log_refusals: bool = False) -> Path:
    """A router.toml for `name` (its certificate must be in `pki`). `access` is the [access]
    table: {"gateways": [...], "routers": [...], "subscribers": {name: {"farms": [...]}}}."""
    cert = pki.issued[name]
    lines = ["[router]", f"name = {_toml(name)}", f"listen = {_toml(list(listen))}",
             f"connect = {_toml(list(connect))}", f"log = {_toml(log)}",
             f"log_refusals = {_toml(log_refusals)}", "retry_initial_ms = 100", "retry_max_ms = 500",
             "", "[tls]", f"ca = {_toml(str(pki.ca.cert))}", f"cert = {_toml(str(cert.cert))}",
             f"key = {_toml(str(cert.key))}", "mutual = true", ""]
    if access is not None:
        lines.append("[access]")
        for key in ("gateways", "routers"):
            lines.append(f"{key} = {_toml(list(access.get(key, [])))}")
        for sub, entry in access.get("subscribers", {}).items():
            lines += ["", f"[access.subscribers.{sub}]"]
            lines += [f"{k} = {_toml(v)}" for k, v in entry.items()]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


class _PipedProc:
    """A subprocess whose stdout+stderr lines are kept in ``lines`` and written to ``log`` by a
    reader thread."""

    log: Path

    def __init__(self) -> None:
        self.proc: subprocess.Popen[str] | None = None
        self.lines: list[str] = []
        self._reader: threading.Thread | None = None

    def _spawn(self, argv: list[str], env: dict[str, str]) -> None:
        self.proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, errors="replace")
        self._reader = threading.Thread(target=pump_lines, args=(self.proc, self.log, self.lines),
                                        daemon=True)
        self._reader.start()

    def _finish(self) -> int:
        """After the process ended: its exit status, the reader joined, the pipe closed."""
        assert self.proc is not None
        rc = self.proc.returncode
        if self._reader is not None:
            self._reader.join(10)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self.proc = None
        return rc


class RouterProc(_PipedProc):
    """``python -m gateway router --config FILE`` in a subprocess; always stopped on exit."""

    def __init__(self, config: Path, log: Path | None = None) -> None:
        super().__init__()
        self.config = config
        self.log = log or config.with_suffix(".log")
        self.endpoints: list[str] = []
        self.zid = ""

    def start(self, timeout: float = DEADLINE) -> RouterProc:
        env = dict(os.environ, PYTHONUNBUFFERED="1", NO_COLOR="1")
        env.pop("RUST_LOG", None)
        self.lines = []  # this run's (the log file keeps earlier runs')
        # Zenoh's log goes to stdout (tracing's default writer), Serra's to stderr: keep both.
        self._spawn([sys.executable, "-m", "gateway", "router", "--config", str(self.config)], env)
        ready = wait_until(lambda: self._ready() or self._died(), timeout, f"{self.config.name} ready")
        if ready == "died":
            self._finish()
            raise AssertionError(f"router {self.config.name} exited: {self.log_text()[-2000:]}")
        return self

    def _ready(self) -> bool:
        for line in self.lines:
            if line.startswith(READY):
                fields = dict(f.split("=", 1) for f in line[len(READY):].split() if "=" in f)
                self.zid = fields["zid"]
                self.endpoints = [e.replace("[::]", "127.0.0.1") for e in fields["listen"].split(",")]
                return True
        return False

    def _died(self) -> str:
        return "died" if self.proc is not None and self.proc.poll() is not None else ""

    @property
    def port(self) -> int:
        return int(self.endpoints[0].rsplit(":", 1)[1])

    def mark(self) -> int:
        """A position in the router's output, for :meth:`since`."""
        return len(self.lines)

    def since(self, mark: int) -> str:
        """What the router printed (this run) after `mark`."""
        return "\n".join(self.lines[mark:])

    def log_text(self) -> str:
        """Everything the router printed so far (this run and earlier runs of the same file)."""
        return self.log.read_text(encoding="utf-8", errors="replace") if self.log.exists() else ""

    def stop(self, timeout: float = DEADLINE, sig: int = signal.SIGTERM) -> int:
        """Signal (SIGTERM) and wait; the router must exit by itself (a hang is a failure)."""
        if self.proc is None:
            return 0
        signal_and_wait(self.proc, sig, timeout, f"router {self.config.name}")
        return self._finish()

    def kill(self) -> None:
        """SIGKILL: a crash, nothing closed cleanly."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._finish()

    def __enter__(self) -> RouterProc:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.proc is None:
            return
        if exc[0] is not None:
            self.kill()
        else:
            self.stop()


def client_config(pki: Pki | None, name: str | None, endpoints: Iterable[str],
                  mutual: bool = True, ca: Path | None = None) -> zenoh.Config:
    """A client-mode config: `name`'s certificate from `pki` (None: no client certificate)."""
    if pki is None:
        return build(client_entries(endpoints, retry=Retry(100, 500)))
    if name is None:
        tls = TlsFiles(ca=ca or pki.ca.cert, mutual=False)
    else:
        tls = pki.tls(name, mutual)
        if ca is not None:
            tls = TlsFiles(ca=ca, cert=tls.cert, key=tls.key, mutual=mutual)
    return build(client_entries(endpoints, tls, retry=Retry(100, 500)))


def open_client(pki: Pki | None, name: str | None, endpoints: Iterable[str], **kw: Any) -> zenoh.Session:
    return zenoh.open(client_config(pki, name, endpoints, **kw))


class Inbox:
    """A subscriber callback that records (key, payload) pairs."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []
        self._lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.items.append((str(sample.key_expr), sample.payload.to_string()))

    def payloads(self) -> list[str]:
        with self._lock:
            return [p for _, p in self.items]

    def has(self, payload: str) -> bool:
        return payload in self.payloads()


class LineProc(_PipedProc):
    """A command in a subprocess whose output is kept (and written to `log`); :meth:`start`
    waits for a line starting with `ready`. Stopped with SIGTERM (a hang is a failure)."""

    def __init__(self, argv: list[str], ready: str, log: Path, env: dict[str, str] | None = None) -> None:
        super().__init__()
        self.argv, self.ready, self.log = argv, ready, log
        self.env = dict(os.environ, PYTHONUNBUFFERED="1", NO_COLOR="1", **(env or {}))

    def start(self, timeout: float = DEADLINE) -> LineProc:
        self._spawn(self.argv, self.env)
        found = wait_until(lambda: self.line(self.ready) or (self.proc is not None and self.proc.poll()
                                                             is not None and "died"),
                           timeout, f"{self.argv[3:5]} ready")
        if found == "died":
            self.stop()
            raise AssertionError(f"{' '.join(self.argv[1:5])} exited: {self.text()[-2000:]}")
        return self

    def line(self, prefix: str) -> str:
        return next((x for x in list(self.lines) if x.startswith(prefix)), "")

    def text(self) -> str:
        return "\n".join(self.lines)

    def stop(self, timeout: float = DEADLINE, sig: int = signal.SIGTERM) -> int:
        if self.proc is None:
            return 0
        signal_and_wait(self.proc, sig, timeout, " ".join(self.argv[1:5]))
        return self._finish()

    def __enter__(self) -> LineProc:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and exc[0] is not None:
            self.proc.kill()
        self.stop()


def subscriber_argv(pki: Pki, name: str, endpoints: Iterable[str], *more: str) -> list[str]:
    """``python -m gateway subscribe`` in client mode with `name`'s certificate."""
    tls = pki.tls(name)
    argv = [sys.executable, "-m", "gateway", "subscribe", "--mode", "client",
            "--tls-ca", str(tls.ca), "--tls-cert", str(tls.cert), "--tls-key", str(tls.key)]
    for e in endpoints:
        argv += ["--connect", e]
    return argv + list(more)


def free_port() -> int:
    """A port nothing listens on right now (for a router started later on it)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]

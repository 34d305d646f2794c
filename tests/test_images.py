"""``make images``: the gateway wheel, its files and declared dependencies, installed into a fresh
venv and run through the shipped units; the units themselves and the firmware bundle are in
test_images_units.py.

The bundles are built once per test worker by images/build.py into a temporary folder (the
``bundles`` fixture, tests/conftest.py). The fresh venv gets the wheel with ``--no-deps
--no-index`` (offline) and sees the test venv's site-packages as a plain path for the
dependencies (numpy, rich, …): ``.pth`` files there are not processed, so neither the editable
install nor the checkout (serra-checkout.pth) is visible from it, and the subprocesses run outside
the checkout. What is checked here is the wheel itself (its files, its data, its declared
dependencies, its commands); that PyPI serves the dependencies is not.
"""

from __future__ import annotations

import os
import re
import secrets
import select
import shlex
import shutil
import socket
import sqlite3
import subprocess
import sys
import sysconfig
import time
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from subprocess import Popen

import pytest

from gateway import protocol
from gateway.store.keys import write_keys
from tests.images_common import build, read_unit
from tests.mcu_fakes.hostenv import ROOT
from tests.test_layering import imported_modules


@dataclass
class Installed:
    python: Path
    cwd: Path  # outside the checkout, so `python -m` cannot pick the repository's gateway/
    env: dict[str, str]

    def run(self, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(self.python), *args], cwd=self.cwd, env=self.env,
                              capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def installed(bundles: Path, tmp_path_factory: pytest.TempPathFactory) -> Installed:
    """The bundle's wheel in a fresh venv (see the module docstring)."""
    base = tmp_path_factory.mktemp("fresh")
    venv = base / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   timeout=120)
    python = venv / "bin" / "python"
    (wheel,) = (bundles / "gateway").glob("serra-*.whl")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet",
                    "--no-deps", "--no-index", str(wheel)], check=True, timeout=300)
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                          check=True, capture_output=True, text=True).stdout.strip()
    deps = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib")}
    Path(site, "serra-test-deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    cwd = base / "work"
    cwd.mkdir()
    return Installed(python, cwd, env)


def _repo_package_files() -> set[str]:
    """gateway/'s files as the build sees them: those git tracks (test_images_source.py)."""
    return {str(p.relative_to(ROOT)) for p in build.tracked("gateway")}


def test_wheel_holds_the_gateway_package_and_nothing_else(bundles: Path) -> None:
    (wheel,) = (bundles / "gateway").glob("serra-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    package = {n for n in names if not n.startswith("serra-")}
    assert all(n.startswith("gateway/") for n in package), sorted(package)
    assert not [n for n in names if "training" in n or n.endswith(".csv.gz")]
    # Every module and data file of gateway/ is in it: a subpackage without __init__.py or a
    # data file no package-data pattern matches would be missing on the Pi.
    missing = _repo_package_files() - package
    assert not missing, f"not in the wheel (package-data in pyproject.toml?): {sorted(missing)}"
    assert "gateway/presets/almeria-palmerillas.toml" in package
    # the project's own licence text beside the metadata's "License-Expression: MIT"
    (licence,) = [n for n in names if n.endswith(".dist-info/licenses/LICENSE")]
    assert b"MIT License" in zipfile.ZipFile(wheel).read(licence)


APPLIANCE_EXTRAS = {"cloud"}
"""Extras of the wheel that gateway/ code may import (the cloud side's PostgreSQL store)."""


def _requires(wheel: Path) -> set[str]:
    """Names the wheel requires: its main dependencies and those of APPLIANCE_EXTRAS."""
    with zipfile.ZipFile(wheel) as z:
        meta = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    reqs = [line.split(":", 1)[1].strip() for line in meta.splitlines()
            if line.startswith("Requires-Dist:")]
    out = set()
    for r in reqs:
        extra = re.search(r"extra\s*==\s*['\"]([^'\"]+)['\"]", r)
        if extra is None or extra[1] in APPLIANCE_EXTRAS:
            out.add(_norm(re.match(r"[A-Za-z0-9._-]+", r)[0]))
    return out


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_wheel_declares_every_library_the_gateway_imports(bundles: Path) -> None:
    import importlib.metadata

    (wheel,) = (bundles / "gateway").glob("serra-*.whl")
    declared = _requires(wheel)
    providers = importlib.metadata.packages_distributions()
    top = {mod.split(".")[0] for f in (ROOT / "gateway").rglob("*.py")
           for _, mod in imported_modules(f)}
    third_party = sorted(top - set(sys.stdlib_module_names) - {"gateway"})
    assert "numpy" in third_party
    undeclared = [f"{m} ({', '.join(providers.get(m, ['not installed']))})" for m in third_party
                  if not {_norm(d) for d in providers.get(m, [])} & declared]
    assert not undeclared, f"imported by gateway/ but not in [project] dependencies: {undeclared}"


def test_installed_wheel_runs_without_the_checkout(installed: Installed) -> None:
    r = installed.run("-c", "import gateway, importlib.util; print(gateway.__file__); "
                      "print(importlib.util.find_spec('training'))")
    assert r.returncode == 0, r.stderr
    where, training = r.stdout.split()
    assert Path(where).is_relative_to(installed.python.parents[1]), where
    assert not Path(where).is_relative_to(ROOT)
    assert training == "None"  # the offline tools are not part of the appliance
    r = installed.run("-m", "gateway", "--help")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("usage: python -m gateway")
    for command in ("calibrate", "replay", "diagnose", "ingest", "export", "run", "subscribe",
                    "status"):
        assert command in r.stdout
    assert "demo" not in r.stdout
    r = installed.run("-m", "gateway", "calibrate", "--help")  # presets come from package data
    assert r.returncode == 0 and "almeria-palmerillas" in r.stdout, r.stderr


def _map_paths(text: str, installed: Installed, root: Path) -> str:
    """The install's paths and the kit's public port → a temp folder and a loopback port."""
    return (text.replace("/opt/serra/venv/bin/python", str(installed.python))
            .replace("/var/lib/serra/", f"{root}/").replace("/etc/serra/", f"{root}/")
            .replace("0.0.0.0:5683", "127.0.0.1:0").replace("tcp/0.0.0.0:7447", "tcp/127.0.0.1:0"))


def install_configs(installed: Installed, bundles: Path, root: Path) -> None:
    """The bundle's default configs into ``root``, their paths and ports mapped."""
    for config in (bundles / "gateway").glob("*.toml"):
        (root / config.name).write_text(_map_paths(config.read_text(), installed, root))


def run_unit_command(name: str, installed: Installed, bundles: Path, root: Path,
                     *more: str) -> subprocess.CompletedProcess[str]:
    """A shipped unit's ExecStart (``more`` after it, e.g. ``--check``, what the bundle README
    has the operator run after an edit) from the fresh venv, to its end, paths mapped into
    ``root`` where the caller put the configs."""
    (cmd,) = read_unit(bundles / "gateway" / name)["ExecStart"]
    return subprocess.run([*shlex.split(_map_paths(cmd, installed, root)), *more],
                          cwd=installed.cwd, env=installed.env, capture_output=True, text=True,
                          timeout=120)


@contextmanager
def run_unit(name: str, installed: Installed, bundles: Path, root: Path,
             install: bool = True) -> Iterator[Popen[str]]:
    """Start a shipped unit's ExecStart from the fresh venv, with the bundle's default configs
    (paths mapped into ``root``; ``install=False``: the caller put them there, edited);
    stopped with SIGTERM, as systemd does, and must exit 0."""
    if install:
        install_configs(installed, bundles, root)
    (cmd,) = read_unit(bundles / "gateway" / name)["ExecStart"]
    log = root / f"{name}.stderr"
    with log.open("w") as err:
        proc = subprocess.Popen(shlex.split(_map_paths(cmd, installed, root)), cwd=installed.cwd,
                                env=installed.env, text=True, stdout=subprocess.PIPE, stderr=err)
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, log.read_text()


def _first_line(proc: Popen[str], deadline: float = 120) -> str:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], deadline)
    return proc.stdout.readline() if ready else ""


def _line_starting(proc: Popen[str], prefix: str, timeout: float = 120) -> str:
    """The first stdout line starting with ``prefix`` ("" at the end of output or the deadline).
    Reads the pipe's descriptor itself: a buffered readline would hide the next lines from
    select."""
    assert proc.stdout is not None
    fd, buf, end = proc.stdout.fileno(), b"", time.monotonic() + timeout
    while (left := end - time.monotonic()) > 0 and select.select([fd], [], [], left)[0]:
        chunk = os.read(fd, 4096)
        if not chunk:
            break
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            if line.decode().startswith(prefix):
                return line.decode()
    return ""


def _send_one_record(sock: socket.socket, host: str, port: int, key: bytes) -> None:
    """Kit 7's first signed record to the ingest at ``host:port``; asserts it is acknowledged
    as stored."""
    rec = protocol.Record(7, 0, 0, 60_000, 0, 60.0, (21.5, 60.0, 15.0, 70.0, 300.0, 2.0, 0),
                          (0,) * 7)
    sock.settimeout(60)
    sock.sendto(protocol.encode_record(rec, key), (host, port))
    ack = protocol.decode_ack(sock.recv(64), key)
    assert (ack.device_id, ack.seq, ack.status) == (7, 0, protocol.ACK_STORED)


def test_installed_wheel_stores_a_record_through_the_shipped_ingest_unit(
        installed: Installed, bundles: Path, tmp_path: Path) -> None:
    key = secrets.token_bytes(32)
    write_keys(tmp_path / "keys.txt", {7: key})
    with run_unit("serra-ingest.service", installed, bundles, tmp_path) as proc, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        line = _first_line(proc)
        assert line.startswith("serra-ingest listening udp"), line
        host, port = line.split()[-1].rsplit(":", 1)
        _send_one_record(sock, host, int(port), key)
    with sqlite3.connect(tmp_path / "serra.db") as db:
        assert db.execute("SELECT count(*) FROM samples").fetchone()[0] == 1


def test_installed_wheel_runs_the_shipped_gateway_unit_from_its_default_config(
        installed: Installed, bundles: Path, tmp_path: Path) -> None:
    """The live gateway from the wheel alone, with the bundle's gateway.toml (paths and ports
    mapped to a temp folder and loopback): its --check, its ready line, a signed record stored and
    acknowledged, the status screen reading the store it wrote, SIGTERM → exit 0."""
    key = secrets.token_bytes(32)
    write_keys(tmp_path / "keys.txt", {7: key})
    install_configs(installed, bundles, tmp_path)
    check = run_unit_command("serra-gateway.service", installed, bundles, tmp_path, "--check")
    assert check.returncode == 0 and "ok: farm demo-farm" in check.stdout, check.stderr
    with run_unit("serra-gateway.service", installed, bundles, tmp_path) as proc, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        line = _line_starting(proc, "serra-gateway ready")
        assert line.startswith("serra-gateway ready udp 127.0.0.1:"), line
        words = line.split()
        host, port = words[words.index("udp") + 1].rsplit(":", 1)
        assert words[words.index("zenoh") + 1].startswith("tcp/127.0.0.1:")
        _send_one_record(sock, host, int(port), key)
        r = installed.run("-m", "gateway", "status", "--db", str(tmp_path / "serra.db"), "--once")
        assert "farm demo-farm · greenhouse north (1/1)" in r.stdout, r.stdout + r.stderr
        assert "   7  north in+out" in r.stdout and "\x1b" not in r.stdout
    with sqlite3.connect(tmp_path / "serra.db") as db:
        assert db.execute("SELECT count(*) FROM samples").fetchone()[0] == 1


def _free_port() -> int:
    """A TCP port nothing listens on now, for the router (its config names a port)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _same_host_router_configs(root: Path, port: int) -> None:
    """The bundle README's "a Zenoh router on this Pi", on the configs in ``root``: the router
    on ``port`` with no upstream and the farm in its access table; the gateway its TLS client
    on 127.0.0.1, with no listener of its own and the farm's certificate."""
    router = root / "router.toml"
    text = (router.read_text().replace("tls/0.0.0.0:7447", f"tls/127.0.0.1:{port}")
            .replace('"farm-a", "farm-b"', '"demo-farm"').replace('["farm-a"]', '["demo-farm"]'))
    router.write_text(re.sub(r"(?m)^connect = \[.*\]", "connect = []", text))
    gateway = root / "gateway.toml"
    text = (gateway.read_text().replace('mode = "peer"', 'mode = "client"')
            .replace("connect = []", f'connect = ["tls/127.0.0.1:{port}"]')
            .replace('listen = ["tcp/127.0.0.1:0"]', "listen = []"))
    gateway.write_text(re.sub(r"(?m)^# (\[zenoh\.tls\]|ca = |cert = |key = )", r"\1", text))


def test_installed_wheel_runs_the_gateway_as_client_of_the_shipped_router_unit(
        installed: Installed, bundles: Path, tmp_path: Path) -> None:
    """Both shipped configs listen on TCP 7447; the bundle README's recipe for a router on the
    gateway's host (the gateway its TLS client) runs both units side by side, linked."""
    r = installed.run("-m", "gateway", "certs", "--out", str(tmp_path / "certs"), "--router",
                      "region-1", "--gateway", "demo-farm")
    assert r.returncode == 0, r.stderr
    write_keys(tmp_path / "keys.txt", {7: secrets.token_bytes(32)})
    install_configs(installed, bundles, tmp_path)
    assert '"tls/0.0.0.0:7447"' in (bundles / "gateway" / "router.toml").read_text()
    assert '"tcp/0.0.0.0:7447"' in (bundles / "gateway" / "gateway.toml").read_text()
    _same_host_router_configs(tmp_path, _free_port())
    check = run_unit_command("serra-router.service", installed, bundles, tmp_path, "--check")
    assert check.returncode == 0, check.stderr
    with run_unit("serra-router.service", installed, bundles, tmp_path, install=False) as router:
        ready = _line_starting(router, "serra router ready")
        assert ready, (tmp_path / "serra-router.service.stderr").read_text()
        with run_unit("serra-gateway.service", installed, bundles, tmp_path, install=False) as gw:
            assert _line_starting(gw, "serra-gateway ready udp 127.0.0.1:")
            end, seen = time.monotonic() + 120, ""
            while time.monotonic() < end and "up: 0 peers, 1 router" not in seen:
                seen = installed.run("-m", "gateway", "status", "--config",
                                     str(tmp_path / "gateway.toml"), "--once").stdout
            assert "up: 0 peers, 1 router" in seen, seen


def test_installed_wheel_checks_a_config_with_the_shipped_ventilation_sensor(
        installed: Installed, bundles: Path, tmp_path: Path) -> None:
    """gateway.toml's comment names a command for the shipped sensor's path; that path, given as
    the greenhouse's vsensor, passes the unit's --check (onnxruntime loads it, from the wheel)."""
    write_keys(tmp_path / "keys.txt", {7: secrets.token_bytes(32)})
    install_configs(installed, bundles, tmp_path)
    config = tmp_path / "gateway.toml"
    text = config.read_text()
    (command,) = re.findall(rf"(?m)^# ({re.escape(str(installed.python))} -c .*)$", text)
    r = subprocess.run(shlex.split(command), cwd=installed.cwd, env=installed.env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    sensor = Path(r.stdout.strip())
    assert sensor.is_file() and sensor.is_relative_to(installed.python.parents[1]), sensor
    config.write_text(text.replace('# vsensor = "ventilation.onnx"', f'vsensor = "{sensor}"'))
    check = run_unit_command("serra-gateway.service", installed, bundles, tmp_path, "--check")
    assert check.returncode == 0 and "ok: farm demo-farm" in check.stdout, check.stderr


CONFIG_ERRORS = {  # unit → (what is wrong in the config it names, what the one line says)
    "serra-gateway.service": [
        (("[gateway]\n", "[gateway]\nfarmm = 'x'\n"), "gateway.toml: gateway.farmm: unknown key"),
        (('farm = "demo-farm"', 'farm = "demo-farm'), "gateway.toml: invalid TOML"),
        (("keys.txt", "nokeys.txt"), "gateway.toml: gateway.keys: cannot read "),
        (('greenhouse = "', 'greenhouse = "no-such-'), "gateway.toml: greenhouse[1].greenhouse: "),
    ],
    "serra-router.service": [  # the certificates it names are not made (no `gateway certs`)
        ((), "router.toml: tls.ca: "),
        (("[router]\n", "[router]\nlisten_on = 1\n"), "router.toml: unknown key 'router.listen_on'"),
    ],
    "serra-ingest.service": [((), "keys.txt: cannot read the keys file")],  # no keys file
    "serra-subscribe.service": [  # no subscriber.toml; the example as shipped: no certificates
        ((), "subscriber.toml: cannot read subscriber config"),
        (("", ""), "subscriber.toml: tls.ca: "),
    ],
}


@pytest.mark.parametrize(("unit", "case"), [(u, i) for u, cases in CONFIG_ERRORS.items()
                                            for i in range(len(cases))])
def test_installed_wheel_exits_78_under_each_shipped_unit_when_its_config_is_wrong(
        installed: Installed, bundles: Path, tmp_path: Path, unit: str, case: int) -> None:
    """A wrong config, a key, a file it names: the unit's own command exits 78 (EX_CONFIG, the
    units' RestartPreventExitStatus=, so systemd does not restart it every 5 s) with one line
    naming the file and the key, before it listens or writes anything."""
    edit, said = CONFIG_ERRORS[unit][case]
    if unit != "serra-ingest.service":
        write_keys(tmp_path / "keys.txt", {7: secrets.token_bytes(32)})
    install_configs(installed, bundles, tmp_path)
    config = tmp_path / {"serra-router.service": "router.toml",
                         "serra-subscribe.service": "subscriber.toml"}.get(unit, "gateway.toml")
    if unit == "serra-subscribe.service" and edit:  # the README's install step
        shutil.copy(bundles / "gateway" / "docs" / "examples" / "subscriber.toml", config)
    if edit:
        old, new = edit
        assert old in config.read_text()
        config.write_text(config.read_text().replace(old, new, 1))
    r = run_unit_command(unit, installed, bundles, tmp_path)
    assert r.returncode == 78 == os.EX_CONFIG, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(f"error: {tmp_path}/"), r.stderr
    assert said in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not r.stdout
    assert not (tmp_path / "serra.db").exists()

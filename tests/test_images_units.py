"""``make images``: the systemd units and install steps of the gateway bundle, the README's deploy
commands, and the firmware bundle (compiled for the ESP32, run on MicroPython). The bundles are
built once per test worker by images/build.py into a temporary folder (the ``bundles`` fixture)."""

from __future__ import annotations

import hashlib
import json
import os
import re
import secrets
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.store.outage import EX_DAMAGED
from tests.images_common import build, read_unit
from tests.mcu_fakes.hostenv import FAKE_PATH, MCU, ROOT, micropython, mpy_env

UNITS = ("serra-gateway.service", "serra-router.service", "serra-ingest.service",
         "serra-subscribe.service")


HARDENING = {  # in every unit
    "User": "serra", "Group": "serra", "NoNewPrivileges": "yes", "ProtectSystem": "strict",
    "ProtectHome": "yes", "PrivateTmp": "yes", "CapabilityBoundingSet": "", "UMask": "0077",
    "RestrictSUIDSGID": "yes", "SystemCallFilter": "@system-service",
}


STATE = {"StateDirectory": "serra", "ReadWritePaths": "/var/lib/serra"}  # units that write


EXEC = {
    "serra-gateway.service": "/opt/serra/venv/bin/python -m gateway run --config /etc/serra/gateway.toml",
    "serra-router.service": "/opt/serra/venv/bin/python -m gateway router --config /etc/serra/router.toml",
    "serra-ingest.service": "/opt/serra/venv/bin/python -m gateway.ingest.service --db "
                            "/var/lib/serra/serra.db --keys /etc/serra/keys.txt --listen 0.0.0.0:5683",
    "serra-subscribe.service": "/opt/serra/venv/bin/python -m gateway subscribe --config "
                               "/etc/serra/subscriber.toml",
}


def test_units_run_the_documented_commands_hardened(bundles: Path) -> None:
    for name in UNITS:
        unit = read_unit(bundles / "gateway" / name)
        assert unit["ExecStart"] == [EXEC[name]], name
        want = HARDENING | (STATE if name != "serra-router.service" else {})
        wrong = {k: unit.get(k) for k, v in want.items() if unit.get(k) != [v]}
        assert not wrong, f"{name}: {wrong}"
        assert unit["WantedBy"] == ["multi-user.target"]
    # the full gateway and the ingest-only unit share the UDP port: one excludes the other
    assert read_unit(bundles / "gateway" / "serra-gateway.service")["Conflicts"] == ["serra-ingest.service"]
    # the cloud subscriber starts after a PostgreSQL and a router of its host, wanting neither
    # (either may live on another host)
    sub = read_unit(bundles / "gateway" / "serra-subscribe.service")
    assert sub["After"] == ["network-online.target postgresql.service serra-router.service"]
    assert sub["Wants"] == ["network-online.target"]


def test_units_stop_on_a_config_error_or_a_damaged_store_and_restart_on_any_other_failure(
        bundles: Path) -> None:
    """Exit 78 (EX_CONFIG: what run, router, subscribe and the ingest service exit on a wrong
    config, see test_images.py and tests/fleet/test_subscribe_systemd.py) and, for the two
    services that keep the store, 65 (EX_DATAERR: a damaged store file) are the statuses
    systemd does not restart on: a wrong config or a damaged file would fail every 5 s for ever,
    a store that cannot be opened, a deleted one, a PostgreSQL not answering at start or a crash
    (exit 1, 2, a signal) may not. No
    ExecStartPre=: systemd applies RestartPreventExitStatus= to the main process only
    (systemd#11868), so a --check there that fails would still be restarted."""
    for name in UNITS:
        unit = read_unit(bundles / "gateway" / name)
        assert unit["Restart"] == ["on-failure"] and unit["RestartSec"] == ["5"], name
        # the services that keep the store stop on a damaged store file too (65, EX_DATAERR:
        # tests/test_store_damaged.py): it would fail the same way every 5 s for ever
        keeps_store = name in ("serra-gateway.service", "serra-ingest.service")
        prevent = f"{os.EX_CONFIG} {EX_DAMAGED}" if keeps_store else str(os.EX_CONFIG)
        assert unit["RestartPreventExitStatus"] == [prevent] == [
            "78 65" if keeps_store else "78"], name
        assert "ExecStartPre" not in unit and "ExecCondition" not in unit, name
        assert "SuccessExitStatus" not in unit, name  # 78 stays a failure: the unit shows failed


def test_units_wait_for_the_services_ready_message(bundles: Path) -> None:
    """Type=notify: `systemctl start` returns once the service sends READY=1, which it does once
    it serves (tests/test_sdnotify.py), and fails on the spot when the service exits before (a
    config error: 78); only the main process may notify. The gateway alone has a watchdog: its
    supervising loop pings every second, the unit allows two minutes."""
    for name in UNITS:
        unit = read_unit(bundles / "gateway" / name)
        assert unit["Type"] == ["notify"] and unit["NotifyAccess"] == ["main"], name
        # above a slow start's 10 s per mute Zenoh endpoint and the estimators' own 120 s
        assert 90 <= int(unit["TimeoutStartSec"][0]) <= 300, name
        assert ("WatchdogSec" in unit) == (name == "serra-gateway.service"), name
    assert read_unit(bundles / "gateway" / "serra-gateway.service")["WatchdogSec"] == ["120"]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
@pytest.mark.parametrize("name", UNITS)
def test_units_pass_systemd_analyze(bundles: Path, tmp_path: Path, name: str) -> None:
    """`verify`: every key known, syntax right; `security`: exposure ≤ 2.5 (systemd's "OK")."""
    text = (bundles / "gateway" / name).read_text(encoding="utf-8")
    unit = tmp_path / name  # the interpreter must exist for verify: point it at this one
    unit.write_text(text.replace("/opt/serra/venv/bin/python", os.path.realpath(sys.executable)))
    r = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0 and not r.stdout.strip() and not r.stderr.strip(), r.stdout + r.stderr
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--threshold=25", str(unit)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout[-400:] + r.stderr


def test_install_steps_create_the_keys_file_0600_and_install_every_shipped_file(bundles: Path) -> None:
    readme = (bundles / "gateway" / "README.md").read_text(encoding="utf-8")
    assert "sudo install -m 0600 -o serra -g serra /dev/null /etc/serra/keys.txt" in readme
    assert "useradd --system" in readme and "python3 -m venv /opt/serra/venv" in readme
    for name in [*UNITS, "gateway.toml", "router.toml", "serra-*.whl", "subscriber.toml"]:
        assert name in readme, name
    shipped = {p.name for p in (bundles / "gateway").iterdir()}
    assert shipped == {*UNITS, "gateway.toml", "router.toml", "README.md", "docs",
                       next(n for n in shipped if n.endswith(".whl"))}
    assert "sudo cp -r docs /opt/serra/" in readme


def test_every_document_the_gateway_bundle_names_is_in_it(bundles: Path) -> None:
    """The configs, the units and the README name docs/*.md (and the units /opt/serra/docs/...):
    the Pi has no checkout, so each is in the bundle's docs/, as in the repository."""
    gw = bundles / "gateway"
    named = set()
    for f in [*UNITS, "gateway.toml", "router.toml", "README.md"]:
        named |= set(re.findall(r"\bdocs/[\w./-]*\w", (gw / f).read_text(encoding="utf-8")))
    assert {"docs/gateway.md", "docs/fleet.md", "docs/wire-format.md"} <= named, named
    missing = sorted(n for n in named if not (gw / n).is_file())
    assert not missing, missing
    assert (gw / "docs/gateway.md").read_bytes() == (ROOT / "docs/gateway.md").read_bytes()


def test_readme_deploy_commands_are_the_bundles_commands(bundles: Path) -> None:
    """The README's Deploy section shows commands from the bundle READMEs, not a diverging copy."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    deploy = readme[readme.index("\n## Deploy"):]
    deploy = deploy[:deploy.find("\n## ", 5) if "\n## " in deploy[5:] else None]
    blocks = re.findall(r"```sh\n(.*?)```", deploy, re.S)
    lines = [ln.strip() for b in blocks for ln in b.splitlines() if ln.strip()
             and not ln.lstrip().startswith("#")]
    assert len(lines) >= 10
    shipped = "".join((bundles / b / "README.md").read_text(encoding="utf-8")
                      for b in ("gateway", "firmware"))
    assert not [ln for ln in lines if ln not in shipped]


def test_firmware_bundle_holds_every_module_compiled_for_the_esp32(bundles: Path) -> None:
    fw = bundles / "firmware"
    for src in build.firmware_sources():
        if src.name == "main.py":
            assert (fw / "main.py").read_bytes() == src.read_bytes()
        else:
            mpy = (fw / src.relative_to(MCU)).with_suffix(".mpy")
            assert mpy.read_bytes()[:2] == b"M\x06", mpy  # .mpy version 6
    manifest = (fw / "MANIFEST.txt").read_text()
    assert "mpy-cross emitting mpy v6" in manifest
    for line in manifest.splitlines():
        if not line.startswith("#"):
            digest, name = line.split()
            assert hashlib.sha256((fw / name).read_bytes()).hexdigest() == digest, name
    readme = (fw / "README.md").read_text()
    assert "mpremote connect PORT cp *.mpy main.py config.json : + reset" in readme


def _run_bundle(fw: Path, code: str) -> subprocess.CompletedProcess[str]:
    """MicroPython with only the bundle (and the fake hardware modules) on its path."""
    exe = micropython()
    assert exe
    env = mpy_env({"MICROPYPATH": f"{FAKE_PATH}:{fw}:.frozen"})  # the board's clock too
    return subprocess.run([exe, "-X", "heapsize=96K", "-c", code], cwd=fw, env=env,
                          capture_output=True, text=True, timeout=60)


@pytest.mark.skipif(micropython() is None, reason="micropython not installed")
def test_firmware_bundle_runs_on_micropython_and_refuses_the_template_key(
        bundles: Path, tmp_path: Path) -> None:
    fw = tmp_path / "firmware"
    shutil.copytree(bundles / "firmware", fw)
    modules = [p.stem for p in fw.glob("*.mpy")]
    r = _run_bundle(fw, f"import {', '.join(modules)}; print('LOADED')")
    assert "LOADED" in r.stdout, r.stdout + r.stderr  # the .mpy files load, no .py beside them
    shutil.copy(fw / "config.template.json", fw / "config.json")
    r = _run_bundle(fw, "import main; main.main()")
    assert "serra: CONFIG ERROR: config.json: field 'key' is not hexadecimal" in r.stdout, r.stdout
    assert not (fw / "boot.cnt").exists()  # stopped before anything started
    cfg = json.loads((fw / "config.template.json").read_text())
    cfg["key"] = secrets.token_hex(32)
    (fw / "config.json").write_text(json.dumps(cfg))
    r = _run_bundle(fw, "import config; c = config.load('config.json'); print('OK', c.device_id)")
    assert f"OK {cfg['device_id']}" in r.stdout, r.stdout + r.stderr


def test_build_refuses_to_empty_a_folder_that_is_not_a_build(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("keep me")
    with pytest.raises(SystemExit) as exc:
        build.main(["--out", str(tmp_path)])
    assert exc.value.code == 2
    assert (tmp_path / "notes.txt").read_text() == "keep me"

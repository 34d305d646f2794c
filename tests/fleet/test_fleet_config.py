"""The fleet settings of the gateway ([zenoh.tls], client retry) and of the subscriber
(subscriber.toml and its command line): what they make, and one-line errors naming the key."""

from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest

from gateway.cli import main
from gateway.cloud.settings import load_settings, parse_settings
from gateway.net.tomlcheck import ConfigError as TableError
from gateway.net.zenohcfg import build, session_entries
from gateway.service.config import ConfigError, parse_config
from tests.fleet.conftest import ACCESS
from tests.fleet.kit import Pki, write_router_toml

GOOD = {
    "gateway": {"farm": "farm-a", "db": "gw.db", "keys": "keys.txt"},
    "greenhouse": [{"name": "north", "greenhouse": "biskra-prototype", "model": "prototype",
                    "inside": 7}],
}


def gateway_raw(pki: Pki, farm: str = "farm-a", **zenoh: object) -> dict:
    tls = pki.tls(farm)
    raw = copy.deepcopy(GOOD)
    raw["zenoh"] = {"mode": "client", "connect": ["tls/127.0.0.1:7447", "tls/127.0.0.1:7448"],
                    "tls": {"ca": str(tls.ca), "cert": str(tls.cert), "key": str(tls.key)}, **zenoh}
    return raw


def test_a_gateway_with_its_farm_certificate(pki: Pki, tmp_path: Path) -> None:
    cfg = parse_config(gateway_raw(pki, retry_initial_ms=100, retry_max_ms=800), "gw.toml", tmp_path)
    z = cfg.zenoh
    assert z.tls is not None and z.tls.cert == pki.issued["farm-a"].cert and z.tls.mutual
    entries = session_entries(z.connect, z.listen, z.tls, z.retry)
    assert entries["transport/link/tls/connect_certificate"] == str(pki.issued["farm-a"].cert)
    assert entries["transport/link/tls/enable_mtls"] is True
    assert "transport/link/tls/listen_certificate" not in entries  # a client does not listen
    assert entries["connect/retry"] == {"period_init_ms": 100, "period_max_ms": 800,
                                        "period_increase_factor": 2.0}
    build(entries)  # Zenoh accepts every key


@pytest.mark.parametrize("change, message", [
    ({"tls": None}, "zenoh.connect[0]: 'tls/127.0.0.1:7447' needs a [zenoh.tls] table"),
    ({"tls": {"cert": "x.pem"}}, "'zenoh.tls.ca' is missing"),
    ({"tls": {"ca": "ca.pem", "pem": "x"}}, "unknown key 'zenoh.tls.pem'"),
    ({"retry_initial_ms": 1000, "retry_max_ms": 500}, "zenoh.retry_max_ms: 500 is below"),
    ({"retry_initial_ms": 0}, "zenoh.retry_initial_ms: 0 is outside 10"),
    ({"listen": ["tls/0.0.0.0:7447"], "mode": "peer", "tls": "no-cert"},
     "zenoh.listen[0]: listening on 'tls/0.0.0.0:7447' needs zenoh.tls.cert"),
])
def test_gateway_tls_errors_name_the_key(change: dict, message: str, pki: Pki, tmp_path: Path) -> None:
    raw = gateway_raw(pki)
    for k, v in change.items():
        if v is None:
            del raw["zenoh"][k]
        elif v == "no-cert":
            raw["zenoh"]["tls"] = {"ca": str(pki.ca.cert), "mutual": False}
        else:
            raw["zenoh"][k] = v
    with pytest.raises(ConfigError) as e:
        parse_config(raw, "gw.toml", tmp_path)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_a_world_readable_key_or_another_farms_certificate_is_refused(pki: Pki, tmp_path: Path) -> None:
    loose = tmp_path / "loose.key"
    loose.write_bytes(pki.issued["farm-a"].key.read_bytes())
    os.chmod(loose, 0o644)
    raw = gateway_raw(pki)
    raw["zenoh"]["tls"]["key"] = str(loose)
    with pytest.raises(ConfigError, match=r"gw.toml: zenoh.tls.key: .*loose.key: private key mode "
                       r"is 0644, .*refusing it \(run: chmod 600 "):
        parse_config(raw, "gw.toml", tmp_path)
    with pytest.raises(ConfigError, match=r"zenoh.tls.cert: .*gateway-farm-b.pem is for 'farm-b', "
                       r"not this gateway's farm 'farm-a'"):
        parse_config(gateway_raw(pki, farm="farm-b"), "gw.toml", tmp_path)


def subscriber_toml(pki: Pki, folder: Path, body: str, name: str = "store") -> Path:
    tls = pki.tls(name)
    path = folder / "subscriber.toml"
    path.write_text(f'[subscribe]\n{body}\n[tls]\nca = "{tls.ca}"\ncert = "{tls.cert}"\n'
                    f'key = "{tls.key}"\n')
    return path


def test_the_subscriber_reads_its_farms_from_the_routers_access_table(pki: Pki, tmp_path: Path) -> None:
    write_router_toml(tmp_path / "cloud.toml", "cloud", pki, access=ACCESS)
    path = subscriber_toml(pki, tmp_path, 'mode = "client"\nconnect = ["tls/127.0.0.1:7447"]\n'
                           'access = "cloud.toml"\ndsn = "dbname=serra"\nhistory = true')
    s = load_settings(path).check()
    assert s.farms == ("farm-a", "farm-b")  # "store" may read every farm ("*")
    assert s.subscriptions() == ["serra/farm-a/**", "serra/farm-b/**"]
    assert s.dsn == "dbname=serra" and s.db is None and s.history
    assert s.zenoh_entries()["transport/link/tls/connect_certificate"] == str(pki.issued["store"].cert)
    reader = load_settings(subscriber_toml(pki, tmp_path, 'access = "cloud.toml"', "reader-b"))
    assert reader.subscriptions() == ["serra/farm-b/**"]


@pytest.mark.parametrize("body, message", [
    ('access = "cloud.toml"\nfarms = ["farm-a"]', "'subscribe.access' and 'farms' both name"),
    ('mode = "router"', "'subscribe.mode' = 'router': expected peer or client"),
    ('mode = "client"', "client mode needs a router in connect"),
    ('connect = ["tcp/127.0.0.1:7447"]\nhistory = true', "history needs the farms"),
    ('db = "x.db"\ndsn = "dbname=x"', "give db (SQLite) or dsn (PostgreSQL), not both"),
    ('conect = []', "unknown key 'subscribe.conect'"),
    ('connect = ["127.0.0.1:7447"]', "connect[0]: '127.0.0.1:7447' is not PROTOCOL/HOST:PORT"),
])
def test_subscriber_settings_errors(body: str, message: str, pki: Pki, tmp_path: Path) -> None:
    write_router_toml(tmp_path / "cloud.toml", "cloud", pki, access=ACCESS)
    with pytest.raises(TableError) as e:
        load_settings(subscriber_toml(pki, tmp_path, body)).check()
    assert message in str(e.value) and "\n" not in str(e.value)


def test_the_subscriber_is_named_by_its_certificate(pki: Pki, tmp_path: Path) -> None:
    write_router_toml(tmp_path / "cloud.toml", "cloud", pki, access=ACCESS)
    with pytest.raises(TableError, match=r"has no 'stranger' \(the CN of"):
        load_settings(subscriber_toml(pki, tmp_path, 'access = "cloud.toml"', "stranger"))
    with pytest.raises(TableError, match="named by its certificate's common name"):
        parse_settings({"subscribe": {"access": "cloud.toml"}}, "s.toml", tmp_path)


def test_subscribe_command_line_errors_are_one_line(pki: Pki, tmp_path: Path, capsys) -> None:
    argv = ["subscribe", "--mode", "client", "--connect", "tls/127.0.0.1:7447", "--db", "x.db"]
    assert main(argv) == 78  # EX_CONFIG
    assert "needs TLS files" in capsys.readouterr().err
    assert main(argv + ["--tls-cert", str(pki.issued["store"].cert)]) == 78  # EX_CONFIG
    assert "--tls-cert/--tls-key need --tls-ca" in capsys.readouterr().err
    assert main(["subscribe", "--connect", "tcp/127.0.0.1:7447"]) == 78  # EX_CONFIG
    assert "give --db FILE (SQLite) or --dsn DSN (PostgreSQL)" in capsys.readouterr().err


def test_the_documented_subscriber_example_parses_and_every_key_is_documented(tmp_path: Path) -> None:
    import re
    import shutil

    from tests.fleet.kit import ROOT, make_pki

    example = ROOT / "docs" / "examples" / "subscriber.toml"
    folder = tmp_path / "etc"
    pki = make_pki(folder / "certs", routers=["cloud-1"], clients=["cloud-store"])
    shutil.copy(example, folder / "subscriber.toml")
    write_router_toml(folder / "router.toml", "cloud-1", pki,
                      access={"gateways": ["farm-a", "farm-b"], "routers": ["cloud-1"],
                              "subscribers": {"cloud-store": {"farms": ["*"], "store": True}}})
    s = load_settings(folder / "subscriber.toml").check()
    assert s.mode == "client" and s.farms == ("farm-a", "farm-b") and s.history
    assert s.dsn and s.connect[0] == "tls/cloud-1.example.org:7447"
    text = example.read_text()
    keys = set(re.findall(r"^#? ?(\w+) = ", text, re.M))
    doc = (ROOT / "docs" / "cloud.md").read_text()
    assert not sorted(k for k in keys if f"`{k}`" not in doc)


def test_router_check_into_a_closed_pipe_ends_without_a_traceback(pki: Pki, tmp_path: Path) -> None:
    """`python -m gateway router --config router.toml --check | head` stops reading early (the
    access table of 60 farms makes ~40 KB of Zenoh config): the command ends quietly, as a
    shell's own tools do, not in a BrokenPipeError traceback."""
    import subprocess
    import sys

    access = dict(ACCESS, gateways=ACCESS["gateways"] + [f"farm-{i}" for i in range(60)])
    config = write_router_toml(tmp_path / "cloud.toml", "cloud", pki, access=access)
    read, write = os.pipe()
    os.close(read)  # the reader is gone before the first write: deterministic
    try:
        r = subprocess.run([sys.executable, "-m", "gateway", "router", "--config", str(config),
                            "--check"], stdout=write, stderr=subprocess.PIPE, text=True,
                           timeout=60, cwd=Path(__file__).resolve().parents[2], check=False)
    finally:
        os.close(write)
    assert "Traceback" not in r.stderr and "BrokenPipeError" not in r.stderr, r.stderr
    assert r.returncode == 1

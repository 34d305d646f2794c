"""router.toml validation, the access table → Zenoh access_control, TLS entries, the CLI."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from gateway.net.acl import AccessSpec, Subscriber, access_control
from gateway.net.routerconf import load_router_config, parse_router_config, router_entries
from gateway.net.tomlcheck import ConfigError
from gateway.net.zenohcfg import TlsFiles, build, client_entries, tls_entries
from tests.fleet.kit import Pki, RouterProc, make_pki

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "images" / "gateway" / "router.toml"


@pytest.fixture()
def example(tmp_path: Path) -> Path:
    """The shipped example with the certificates it names made in certs/ beside it."""
    make_pki(tmp_path / "certs", routers=["region-1"])
    return Path(shutil.copy(EXAMPLE, tmp_path / "router.toml"))


def test_the_shipped_example_is_valid_and_zenoh_accepts_it(example: Path) -> None:
    s = load_router_config(example)
    assert s.name == "region-1" and s.listen == ("tls/0.0.0.0:7447",) and len(s.connect) == 2
    assert s.tls is not None and s.tls.key == example.parent / "certs" / "router-region-1.key"
    assert s.access is not None and s.access.subscriptions("cloud-store") == [
        "serra/farm-a/**", "serra/farm-b/**"]
    entries = router_entries(s)
    assert entries["mode"] == "router" and entries["connect/exit_on_failure"] is False
    assert entries["transport/link/tls/enable_mtls"] is True
    assert entries["access_control"]["default_permission"] == "deny"
    build(entries)  # Zenoh's own validation of every key


def _parse(tmp: Path, pki: Pki, text: str) -> object:
    body = (f'[tls]\nca = "{pki.ca.cert}"\ncert = "{pki.issued["cloud"].cert}"\n'
            f'key = "{pki.issued["cloud"].key}"\n' + text)
    return parse_router_config(tomllib.loads(body), "r.toml", tmp)


@pytest.mark.parametrize("text, error", [
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\nport = 1\n', "unknown key 'router.port'"),
    ('[router]\nlisten = []\n', "'router.listen' is missing"),
    ('[router]\nlisten = ["tls/127.0.0.1"]\n', "'router.listen[0]'"),
    ('[router]\nlisten = ["udp/127.0.0.1:7447"]\n', "protocol 'udp'"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\nconnect = [7447]\n', "'router.connect[0]' must be"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\nlog = "loud"\n', "'router.log' = 'loud'"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\nretry_initial_ms = 0\n', "'router.retry_initial_ms'"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\n[access]\ngateways = ["farm-a"]\n'
     '[access.subscribers.s]\nfarms = ["farm-z"]\n', "'access.subscribers.s.farms[0]' = 'farm-z'"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\n[access]\ngateways = ["farm a"]\n', "'access.gateways[0]'"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\n[access]\ngateways = ["x"]\nrouters = ["x"]\n',
     "two roles"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\n[access]\ngateways = ["x"]\n[access.subscribers.s]\n',
     "'access.subscribers.s.farms' is missing"),
    ('[router]\nlisten = ["tls/127.0.0.1:0"]\n[access]\nsubscribers = 3\n', "'access.subscribers' must be"),
])
def test_router_config_errors_name_the_key(pki: Pki, tmp_path: Path, text: str, error: str) -> None:
    with pytest.raises(ConfigError) as err:
        _parse(tmp_path, pki, text)
    assert error in str(err.value) and str(err.value).startswith("r.toml")


def test_security_is_consistent(pki: Pki, tmp_path: Path) -> None:
    plain = {"router": {"listen": ["tls/127.0.0.1:0"]}}
    with pytest.raises(ConfigError, match="needs a \\[tls\\] section"):
        parse_router_config(plain, "r.toml", tmp_path)
    acl_no_tls = {"router": {"listen": ["tcp/127.0.0.1:0"]}, "access": {"gateways": ["farm-a"]}}
    with pytest.raises(ConfigError, match="identifies clients by their certificates"):
        parse_router_config(acl_no_tls, "r.toml", tmp_path)
    with pytest.raises(ConfigError, match="'tls.mutual' must be true"):
        _parse(tmp_path, pki, 'mutual = false\n[router]\nlisten = ["tls/127.0.0.1:0"]\n'
               '[access]\ngateways = ["farm-a"]\n')
    loose = tmp_path / "loose.key"
    loose.write_bytes(pki.issued["cloud"].key.read_bytes())
    loose.chmod(0o644)
    raw = {"router": {"listen": ["tls/127.0.0.1:0"]},
           "tls": {"ca": str(pki.ca.cert), "cert": str(pki.issued["cloud"].cert), "key": "loose.key"}}
    with pytest.raises(ConfigError) as err:
        parse_router_config(raw, "r.toml", tmp_path)  # relative path: from the config's folder
    assert f"r.toml: tls.key: {loose}: private key mode is 0644" in str(err.value)
    tcp_only = parse_router_config({"router": {"listen": ["tcp/127.0.0.1:0"]}}, "r.toml", tmp_path)
    assert "unencrypted" in tcp_only.warnings()[0]


def test_access_table_to_zenoh_rules() -> None:
    spec = AccessSpec(gateways=("farm-a", "farm-b"), routers=("cloud",),
                      subscribers=(Subscriber("store", ("*",), store=True),
                                   Subscriber("reader", ("farm-b",))))
    acl = access_control(spec)
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["gateway-in:farm-a"]["key_exprs"] == ["serra/farm-a/**", "serra/farm-a/**/@adv/**"]
    assert rules["gateway-in:farm-a"]["flows"] == ["ingress"]
    assert "put" in rules["gateway-in:farm-a"]["messages"]
    assert "put" not in rules["gateway-out:farm-a"]["messages"]  # nothing of others flows to it
    assert "declare_subscriber" not in rules["gateway-in:farm-a"]["messages"]
    assert rules["reader-out:*"]["key_exprs"][0] == "serra/**"
    policies = {p["id"]: p for p in acl["policies"]}
    assert policies["policy:subscriber:reader"]["rules"] == ["reader-in:farm-b", "reader-out:farm-b"]
    assert "store-in:*" in policies["policy:subscriber:store"]["rules"]
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert subjects["gateway:farm-b"] == {"id": "gateway:farm-b", "cert_common_names": ["farm-b"],
                                          "link_protocols": ["tls"]}
    assert subjects["routers"]["cert_common_names"] == ["cloud"]
    assert spec.subscriptions("reader") == ["serra/farm-b/**"]
    build({"mode": "router", "access_control": acl})


def test_client_entries_for_the_gateway_and_subscriber_configs(pki: Pki) -> None:
    tls = pki.tls("farm-a")
    e = client_entries(["tls/127.0.0.1:7447", "tls/127.0.0.1:7448"], tls)
    assert e["mode"] == "client" and e["connect/endpoints"][1] == "tls/127.0.0.1:7448"
    assert e["transport/link/tls/connect_certificate"] == str(tls.cert)
    assert "transport/link/tls/listen_certificate" not in e
    listen_only = tls_entries(tls, listen=True, connect=False)
    assert listen_only["transport/link/tls/listen_private_key"] == str(tls.key)
    assert "transport/link/tls/connect_private_key" not in listen_only
    with pytest.raises(ConfigError, match="needs a \\[tls\\] section"):
        client_entries(["tls/127.0.0.1:7447"])
    with pytest.raises(Exception, match="mutual TLS needs"):
        client_entries(["tls/127.0.0.1:7447"], TlsFiles(ca=pki.ca.cert))
    build(e)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_router_command_check_and_errors(example: Path, tmp_path: Path) -> None:
    r = _cli("router", "--config", str(example), "--check")
    assert r.returncode == 0, r.stderr
    assert '"access_control"' in r.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text('[router]\nlisten = ["tls/127.0.0.1:0"]\nlisten_on = 1\n')
    r = _cli("router", "--config", str(bad))
    assert r.returncode == os.EX_CONFIG and r.stderr.count("\n") == 1  # 78: not restarted
    assert "unknown key 'router.listen_on'" in r.stderr
    r = _cli("router", "--config", str(tmp_path / "none.toml"))
    assert r.returncode == os.EX_CONFIG and "cannot read router config" in r.stderr


def test_router_command_stops_cleanly_on_sigint(tmp_path: Path) -> None:
    config = tmp_path / "plain.toml"
    config.write_text('[router]\nname = "lab"\nlisten = ["tcp/127.0.0.1:0"]\n')
    router = RouterProc(config).start()
    try:
        assert router.endpoints[0].startswith("tcp/127.0.0.1:") and router.port > 0
        assert "access=off" in router.since(0)
    finally:
        rc = router.stop(sig=signal.SIGINT)
    out = router.log_text()
    assert rc == 0, out
    assert "Traceback" not in out and "router lab: stopping" in out and "unencrypted" in out

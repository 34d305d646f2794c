"""Serra's settings → Zenoh config entries: endpoints, TLS / mutual TLS, reconnection.

Everything here returns *flat entries*: a dict of Zenoh config paths to JSON values
(``{"transport/link/tls/root_ca_certificate": "/etc/serra/ca.pem", ...}``). Entries from
several builders are merged with ``|`` and applied with :func:`build` (or passed as the
``extra`` of another config builder), so the router, the gateway and the subscriber all get
their TLS section from one function, :func:`tls_entries`, fed by one TOML table, ``[tls]``
(:func:`parse_tls`)::

    [tls]
    ca = "certs/ca.pem"          # the fleet CA: peers must present a certificate it signed
    cert = "certs/gateway-farm-a.pem"
    key = "certs/gateway-farm-a.key"   # mode 0600, else refused
    mutual = true                # mutual TLS (default): both sides present a certificate
    verify_name = true           # a client checks the router's name against its SAN

Key names were checked against eclipse-zenoh 1.10 (``transport/link/tls/...``; a wrong key is
rejected by Zenoh itself, and :func:`build` names it).
"""

from __future__ import annotations

import ipaddress
import json
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gateway.net.certs import CertError, check_key_file, load_certificate
from gateway.net.tomlcheck import ConfigError, Table

PROTOCOLS = ("tcp", "tls")
_ENDPOINT = re.compile(r"^(?P<proto>[a-z]+)/(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>\d{1,5})$")
TLS_KEYS = ("ca", "cert", "key", "mutual", "verify_name")


@dataclass(frozen=True)
class TlsFiles:
    """The PEM files of one side of TLS links (a router, a gateway, a subscriber)."""

    ca: Path  # the fleet CA that signs every certificate
    cert: Path | None = None  # this side's certificate (its CN is its identity for the ACL)
    key: Path | None = None  # its private key, mode 0600
    mutual: bool = True  # mutual TLS: the listening side requires a client certificate
    verify_name: bool = True  # a connecting side checks the server's SAN against the endpoint

    def check(self, where: str = "tls") -> None:
        """Files readable, certificates parse, key mode 0600; else CertError naming the key
        (``where.ca``, ``where.key``...) and the file."""

        def named(key: str, fn: Callable[[Path], object], path: Path) -> None:
            try:
                fn(path)
            except CertError as exc:
                raise CertError(f"{where}.{key}: {exc}") from None

        named("ca", load_certificate, self.ca)
        if (self.cert is None) != (self.key is None):
            raise CertError(f"{where}: give both 'cert' and 'key', or neither")
        if self.cert is not None and self.key is not None:
            named("cert", load_certificate, self.cert)
            named("key", check_key_file, self.key)
        elif self.mutual:
            raise CertError(f"{where}: mutual TLS needs this side's 'cert' and 'key'")


def check_endpoint(text: str, where: str = "endpoint") -> str:
    """``tcp/HOST:PORT`` or ``tls/HOST:PORT`` (HOST a name, an IPv4 or a [bracketed] IPv6)."""
    m = _ENDPOINT.match(text)
    if not m:
        raise ConfigError(f"{where}: {text!r} is not PROTOCOL/HOST:PORT (e.g. tls/192.0.2.7:7447)")
    if m["proto"] not in PROTOCOLS:
        raise ConfigError(f"{where}: protocol {m['proto']!r} in {text!r} is not one of "
                          f"{', '.join(PROTOCOLS)}")
    if int(m["port"]) > 65535:
        raise ConfigError(f"{where}: port {m['port']} in {text!r} is above 65535")
    host = m["host"].strip("[]")
    if m["host"].startswith("["):
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ConfigError(f"{where}: {m['host']} in {text!r} is not an IPv6 address") from None
    return text


def tls_entries(tls: TlsFiles, *, listen: bool, connect: bool = True) -> dict[str, Any]:
    """The ``transport/link/tls`` entries: `listen` for a side that accepts TLS links (a
    router), `connect` for a side that opens them (every client; a router with upstreams)."""
    tls.check()
    base = "transport/link/tls/"
    out: dict[str, Any] = {
        base + "root_ca_certificate": str(tls.ca),
        base + "enable_mtls": tls.mutual,
        base + "verify_name_on_connect": tls.verify_name,
    }
    if tls.cert is not None and tls.key is not None:
        if listen:
            out[base + "listen_certificate"] = str(tls.cert)
            out[base + "listen_private_key"] = str(tls.key)
        if connect:
            out[base + "connect_certificate"] = str(tls.cert)
            out[base + "connect_private_key"] = str(tls.key)
    return out


@dataclass(frozen=True)
class Retry:
    """How a side re-opens a lost link: first wait, longest wait [ms], growth factor."""

    initial_ms: int = 500
    max_ms: int = 4000
    factor: float = 2.0


def endpoint_entries(listen: Iterable[str] = (), connect: Iterable[str] = (),
                     retry: Retry = Retry()) -> dict[str, Any]:
    listen, connect = list(listen), list(connect)
    for i, e in enumerate(listen):
        check_endpoint(e, f"listen[{i}]")
    for i, e in enumerate(connect):
        check_endpoint(e, f"connect[{i}]")
    out: dict[str, Any] = {}
    if listen:
        out["listen/endpoints"] = listen
    if connect:
        out["connect/endpoints"] = connect
        out["connect/retry"] = {"period_init_ms": retry.initial_ms, "period_max_ms": retry.max_ms,
                                "period_increase_factor": retry.factor}
    return out


def base_entries(mode: str, *, multicast: bool = False, gossip: bool = False) -> dict[str, Any]:
    """Mode and scouting: no multicast scouting by default (explicit endpoints only)."""
    if mode not in ("router", "peer", "client"):
        raise ConfigError(f"mode {mode!r}: expected router, peer or client")
    return {"mode": mode, "scouting/multicast/enabled": multicast, "scouting/gossip/enabled": gossip}


def client_entries(connect: Iterable[str], tls: TlsFiles | None = None,
                   retry: Retry = Retry()) -> dict[str, Any]:
    """A client of one or more routers (a gateway, a subscriber). With several endpoints the
    client uses one at a time and moves to another when its link is lost (docs/fleet.md)."""
    connect = list(connect)
    if not connect:
        raise ConfigError("connect: a client needs at least one router endpoint")
    out = base_entries("client") | endpoint_entries(connect=connect, retry=retry)
    if any(e.startswith("tls/") for e in connect):
        if tls is None:
            raise ConfigError("connect: a tls/ endpoint needs a [tls] section")
        out |= tls_entries(tls, listen=False)
    return out


def session_entries(connect: Iterable[str] = (), listen: Iterable[str] = (),
                    tls: TlsFiles | None = None, retry: Retry = Retry()) -> dict[str, Any]:
    """TLS and reconnection entries of a gateway or subscriber session, to add to the mode and
    endpoints its own config builder sets (``gateway.publish.zconfig.build(extra=...)``)."""
    connect, listen = list(connect), list(listen)
    out: dict[str, Any] = {}
    if connect:
        out["connect/retry"] = endpoint_entries(connect=connect, retry=retry)["connect/retry"]
    if tls is not None:
        out |= tls_entries(tls, listen=any(e.startswith("tls/") for e in listen),
                           connect=bool(connect))
    return out


def parse_tls(table: Table, base: Path) -> TlsFiles | None:
    """The ``[tls]`` table (None when absent or empty); paths relative to the config's folder."""
    if not table.raw:
        return None
    table.only(TLS_KEYS)
    ca = table.path("ca", base, required=True)
    assert ca is not None
    tls = TlsFiles(ca=ca, cert=table.path("cert", base), key=table.path("key", base),
                   mutual=table.bool("mutual", True), verify_name=table.bool("verify_name", True))
    try:
        tls.check(f"{table.source}: {table.where}")
    except CertError as exc:
        raise ConfigError(str(exc)) from None
    return tls


def build(entries: Mapping[str, Any]) -> Any:
    """A ``zenoh.Config`` with `entries` inserted; a key Zenoh rejects raises ConfigError."""
    import zenoh

    conf = zenoh.Config()
    for path, value in entries.items():
        try:
            conf.insert_json5(path, json.dumps(value))
        except zenoh.ZError as exc:
            raise ConfigError(f"zenoh config '{path}' = {json.dumps(value)[:120]}: "
                              f"{str(exc).split(' at /')[0]}") from None
    return conf

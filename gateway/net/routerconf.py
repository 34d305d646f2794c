"""``router.toml`` → RouterSettings → Zenoh config entries (validated at start, errors name the key).

The documented example is ``images/gateway/router.toml``; docs/fleet.md explains it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.net.acl import AccessSpec, access_control, parse_access
from gateway.net.tomlcheck import ConfigError, Table
from gateway.net.zenohcfg import (
    Retry,
    TlsFiles,
    base_entries,
    check_endpoint,
    endpoint_entries,
    parse_tls,
    tls_entries,
)
from gateway.tomlfile import read_toml

LOG_LEVELS = ("error", "warn", "info", "debug", "trace")
ACL_LOG_TARGET = "zenoh::net::routing::interceptor::access_control"
ROUTER_KEYS = ("name", "listen", "connect", "log", "log_refusals", "retry_initial_ms", "retry_max_ms")


@dataclass(frozen=True)
class RouterSettings:
    source: str  # the TOML file, for messages
    name: str
    listen: tuple[str, ...]
    connect: tuple[str, ...] = ()  # upstream routers (a router links to every one of them)
    tls: TlsFiles | None = None
    access: AccessSpec | None = None
    log_level: str = "warn"
    log_refusals: bool = False  # every access-control decision at zenoh's trace level
    retry: Retry = field(default_factory=Retry)
    extra: dict[str, Any] = field(default_factory=dict)  # [zenoh]: raw config entries

    def log_filter(self) -> str:
        """The Zenoh log filter (RUST_LOG syntax) these settings ask for."""
        text = self.log_level
        if self.log_refusals:
            text += f",{ACL_LOG_TARGET}=trace"
        elif self.access is not None and self.access.enabled and self.log_level in ("error", "warn"):
            text += f",{ACL_LOG_TARGET}=info"  # a session whose certificate has no rights
        return text

    def warnings(self) -> list[str]:
        out = []
        plain = [e for e in self.listen if not e.startswith("tls/")]
        if plain and self.access is not None and self.access.enabled:
            out.append(f"{self.source}: router.listen {', '.join(plain)}: clients on a plain "
                       "TCP link present no certificate, so the access control denies them "
                       "everything")
        elif plain:
            out.append(f"{self.source}: router.listen {', '.join(plain)}: unencrypted, "
                       "no access control; use it on a trusted network only")
        return out


def load_router_config(path: str | Path) -> RouterSettings:
    path = Path(path)
    raw = read_toml(path, ConfigError, "router config")
    return parse_router_config(raw, str(path), path.resolve().parent)


def parse_router_config(raw: dict[str, Any], source: str, base: Path) -> RouterSettings:
    top = Table(raw, source)
    top.only(("router", "tls", "access", "zenoh"))
    r = top.table("router")
    r.only(ROUTER_KEYS)
    listen = r.strings("listen")
    if not listen:
        raise r.fail("listen", "is missing: give at least one endpoint, e.g. [\"tls/0.0.0.0:7447\"]")
    connect = r.strings("connect")
    for key, endpoints in (("listen", listen), ("connect", connect)):
        for i, e in enumerate(endpoints):
            check_endpoint(e, f"{source}: '{r.where}.{key}[{i}]'")
    level = r.str("log", "warn") or "warn"
    if level not in LOG_LEVELS:
        raise r.fail("log", f"= {level!r}: expected one of {', '.join(LOG_LEVELS)}")
    retry = Retry(_ms(r, "retry_initial_ms", Retry.initial_ms), _ms(r, "retry_max_ms", Retry.max_ms))
    if retry.max_ms < retry.initial_ms:
        raise r.fail("retry_max_ms", "must not be below retry_initial_ms")
    tls = parse_tls(top.table("tls"), base)
    access = parse_access(top.table("access"))
    _check_security(source, listen, connect, tls, access)
    extra = top.table("zenoh").raw
    name = r.str("name") or Path(source).stem
    return RouterSettings(source, name, listen, connect, tls, access, level,
                          r.bool("log_refusals", False), retry, dict(extra))


def _ms(table: Table, key: str, default: int) -> int:
    value = table.raw.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or not 10 <= value <= 3_600_000:
        raise table.fail(key, f"must be a whole number of milliseconds in 10..3600000, got {value!r}")
    return value


def _check_security(source: str, listen: tuple[str, ...], connect: tuple[str, ...],
                    tls: TlsFiles | None, access: AccessSpec | None) -> None:
    uses_tls = [e for e in listen + connect if e.startswith("tls/")]
    if uses_tls and tls is None:
        raise ConfigError(f"{source}: {uses_tls[0]} needs a [tls] section (ca, cert, key)")
    if tls is not None and tls.cert is None and any(e.startswith("tls/") for e in listen):
        raise ConfigError(f"{source}: 'tls.cert' and 'tls.key' are required to listen on tls/")
    if access is not None and access.enabled:
        if tls is None:
            raise ConfigError(f"{source}: [access] identifies clients by their certificates; "
                              "add [tls] with mutual = true and tls/ endpoints")
        if not tls.mutual:
            raise ConfigError(f"{source}: 'tls.mutual' must be true when [access] is enabled "
                              "(without a client certificate there is no name to check)")


def router_entries(s: RouterSettings) -> dict[str, Any]:
    """Flat Zenoh config entries of a router (see gateway.net.zenohcfg.build)."""
    out = base_entries("router") | endpoint_entries(s.listen, s.connect, s.retry)
    if s.connect:
        # Upstream links are retried for ever, in the background: a router starts (and serves
        # its own clients) while the cloud is unreachable.
        out |= {"connect/timeout_ms": -1, "connect/exit_on_failure": False}
    out["adminspace/enabled"] = True  # read-only; the router reads its own bound locators
    out["adminspace/permissions"] = {"read": True, "write": False}
    if s.tls is not None:
        out |= tls_entries(s.tls, listen=True, connect=bool(s.connect))
    if s.access is not None:
        out["access_control"] = access_control(s.access)
    out |= s.extra
    return out

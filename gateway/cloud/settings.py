"""``subscribe --config subscriber.toml`` → SubscribeSettings (command-line options override it).

The documented example is ``docs/examples/subscriber.toml``; every error names the key::

    [subscribe]
    mode = "client"
    connect = ["tls/cloud-1.example.org:7447", "tls/cloud-2.example.org:7447"]
    farms = ["farm-a", "farm-b"]     # one subscription per farm (behind the access control)
    # access = "router.toml"         # or: the farms this certificate may read in that [access]
    dsn = "host=/run/postgresql dbname=serra user=serra"   # PostgreSQL; else db = "cloud.db"
    history = true                   # answer history queries for those farms from the store

    [tls]
    ca = "certs/ca.pem"
    cert = "certs/client-cloud-store.pem"
    key = "certs/client-cloud-store.key"
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from gateway.net.acl import ALL, parse_access
from gateway.net.certs import CertError, common_name, load_certificate
from gateway.net.tomlcheck import ConfigError, Table
from gateway.net.zenohcfg import Retry, TlsFiles, check_endpoint, parse_tls, session_entries
from gateway.tomlfile import read_toml

KEYS = ("mode", "connect", "listen", "keys", "farms", "access", "db", "dsn", "schema", "history",
        "retry_initial_ms", "retry_max_ms")


@dataclass(frozen=True)
class SubscribeSettings:
    source: str = "command line"
    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    keys: tuple[str, ...] = ()  # explicit key expressions (default: serra/**)
    farms: tuple[str, ...] = ()  # one subscription serra/<farm>/** each
    db: Path | None = None  # SQLite (the embedded default)
    dsn: str | None = None  # PostgreSQL
    schema: str = "serra"
    history: bool = False
    tls: TlsFiles | None = None
    retry: Retry = field(default_factory=Retry)

    def subscriptions(self) -> list[str]:
        if self.keys:
            return list(self.keys)
        return [f"serra/{f}/**" for f in self.farms] or ["serra/**"]

    def zenoh_entries(self) -> dict[str, Any]:
        return session_entries(self.connect, self.listen, self.tls, self.retry)

    def check(self) -> SubscribeSettings:
        """Cross-key checks; returns self."""
        for key in ("connect", "listen"):
            for i, e in enumerate(getattr(self, key)):
                check_endpoint(e, f"{self.source}: {key}[{i}]")
                if e.startswith("tls/") and self.tls is None:
                    raise ConfigError(f"{self.source}: {key}[{i}] {e!r} needs TLS files "
                                      "([tls] ca, cert, key, or --tls-ca/--tls-cert/--tls-key)")
        # the keys are named as the file spells them, the options as the command line does
        if self.mode == "client" and not self.connect:
            raise ConfigError(f"{self.source}: client mode needs a router in connect "
                              "(--connect ENDPOINT)")
        if self.history and not self.farms:
            raise ConfigError(f"{self.source}: history needs the farms it answers for "
                              "(farms, access, or --farm)")
        if self.db is not None and self.dsn:
            raise ConfigError(f"{self.source}: give db (SQLite) or dsn (PostgreSQL), not both "
                              "(--db or --dsn)")
        return self


def load_settings(path: str | Path) -> SubscribeSettings:
    path = Path(path)
    raw = read_toml(path, ConfigError, "subscriber config")
    return parse_settings(raw, str(path), path.resolve().parent)


def parse_settings(raw: dict[str, Any], source: str, base: Path) -> SubscribeSettings:
    top = Table(raw, source)
    top.only(("subscribe", "tls"))
    t = top.table("subscribe")
    t.only(KEYS)
    mode = t.str("mode", "peer") or "peer"
    if mode not in ("peer", "client"):
        raise t.fail("mode", f"= {mode!r}: expected peer or client")
    tls = parse_tls(top.table("tls"), base)
    farms = t.strings("farms")
    access = t.path("access", base)
    if access is not None:
        if farms:
            raise t.fail("access", "and 'farms' both name the farms: give one")
        farms = farms_from_access(access, tls)
    retry = Retry(_ms(t, "retry_initial_ms", Retry.initial_ms), _ms(t, "retry_max_ms", Retry.max_ms))
    db = t.path("db", base)
    return SubscribeSettings(source, mode, t.strings("connect"), t.strings("listen"),
                             t.strings("keys"), farms, db, t.str("dsn"), t.str("schema", "serra") or "serra",
                             t.bool("history", False), tls, retry)


def _ms(t: Table, key: str, default: int) -> int:
    value = t.raw.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or not 10 <= value <= 3_600_000:
        raise t.fail(key, f"must be a whole number of milliseconds in 10..3600000, got {value!r}")
    return value


def farms_from_access(router_toml: Path, tls: TlsFiles | None) -> tuple[str, ...]:
    """The farms this subscriber's certificate may read in a router's ``[access]`` table."""
    if tls is None or tls.cert is None:
        raise ConfigError(f"access = {str(router_toml)!r}: the subscriber is named by its "
                          "certificate's common name: give [tls] cert")
    try:
        name = common_name(load_certificate(tls.cert))
    except (OSError, CertError) as exc:
        raise ConfigError(f"{tls.cert}: {exc}") from None
    raw = read_toml(router_toml, ConfigError, "router config")
    spec = parse_access(Table(raw, str(router_toml)).table("access"))
    if spec is None:
        raise ConfigError(f"{router_toml}: no [access] table")
    try:
        sub = spec.subscriber(name)
    except KeyError:
        raise ConfigError(f"{router_toml}: [access.subscribers] has no {name!r} (the CN of "
                          f"{tls.cert})") from None
    return spec.gateways if ALL in sub.farms else sub.farms


def with_overrides(s: SubscribeSettings, **given: Any) -> SubscribeSettings:
    """`s` with the command-line values that were given (None or empty: not given)."""
    return replace(s, **{k: v for k, v in given.items() if v not in (None, (), [], False)})

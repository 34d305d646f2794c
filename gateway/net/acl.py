"""Who may say what: a compact TOML description → Zenoh's ``access_control`` (default deny).

Identities are the common names (CN) of the mutual-TLS certificates (gateway.net.certs)::

    [access]
    gateways = ["farm-a", "farm-b"]   # a gateway's CN is its farm
    routers = ["cloud", "region-1"]   # other routers: trusted with all of serra/**

    [access.subscribers.cloud-store]
    farms = ["*"]                     # every farm
    store = true                      # also answers history queries (the cloud history store)

    [access.subscribers.agronomist-a]
    farms = ["farm-a"]

What each identity may do on a router, for its farms' keys ``serra/<farm>/**`` (and the
``serra/<farm>/**/@adv/**`` keys of Zenoh's advanced pub/sub: cache, miss detection, liveliness):

* a gateway: put, declare a queryable and reply (history), declare liveliness tokens; the
  router may send it the subscriptions and queries on its farm (so its publisher sees who
  listens and its history queryable gets the queries);
* a subscriber: subscribe and query (data and liveliness); the router may send it puts,
  replies and liveliness tokens; with ``store = true`` also declare a queryable and reply.
  It declares one subscription per farm (:meth:`AccessSpec.subscriptions`): a gateway is only
  told of subscriptions inside its farm, so a ``serra/**`` subscription is invisible to it;
* a router: everything under ``serra/**`` both ways.

Everything else is denied: another farm's keys, a client without a listed CN, a plain TCP link.
Rules are evaluated on every router the message crosses, on the link it arrives by (ingress)
and the link it leaves by (egress).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from gateway.net.certs import CertError, check_name
from gateway.net.tomlcheck import ConfigError, Table

ALL = "*"
ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
GATEWAY_IN = ("put", "declare_queryable", "reply", "liveliness_token")
GATEWAY_OUT = ("declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query")
READER_IN = ("declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query")
READER_OUT = ("put", "reply", "liveliness_token")
STORE_IN = ("declare_queryable", "reply")
STORE_OUT = ("query",)


@dataclass(frozen=True)
class Subscriber:
    name: str  # its certificate's CN
    farms: tuple[str, ...]  # farms it may read ("*" = all)
    store: bool = False  # may also answer history queries on those farms


@dataclass(frozen=True)
class AccessSpec:
    gateways: tuple[str, ...] = ()
    subscribers: tuple[Subscriber, ...] = ()
    routers: tuple[str, ...] = ()
    prefix: str = "serra"
    enabled: bool = True

    def subscriber(self, name: str) -> Subscriber:
        for sub in self.subscribers:
            if sub.name == name:
                return sub
        raise KeyError(f"no subscriber {name!r} in the access table")

    def subscriptions(self, name: str) -> list[str]:
        """What subscriber `name` should declare: one ``serra/<farm>/**`` per farm it may read
        ("*" = every gateway's farm). A gateway's publisher only sees (matches) subscriptions
        inside its own farm, and a Zenoh publisher that matches nobody drops its puts: a
        ``serra/**`` subscription would pass the ACL for a "*" subscriber but never be seen by
        the gateways (docs/fleet.md)."""
        sub = self.subscriber(name)
        farms = self.gateways if ALL in sub.farms else sub.farms
        return [f"{self.prefix}/{farm}/**" for farm in farms]

    def farm_keys(self, farm: str) -> list[str]:
        """Key expressions of one farm (or all with "*"), including advanced pub/sub's."""
        root = f"{self.prefix}/**" if farm == ALL else f"{self.prefix}/{farm}/**"
        return [root, f"{root}/@adv/**"]


def parse_access(table: Table) -> AccessSpec | None:
    """The ``[access]`` table → AccessSpec (None when absent); errors name the key."""
    if not table.raw:
        return None
    table.only(("enabled", "prefix", "gateways", "routers", "subscribers"))
    prefix = table.str("prefix", "serra") or "serra"
    _name(table, "prefix", prefix)
    gateways = table.strings("gateways")
    routers = table.strings("routers")
    for i, g in enumerate(gateways):
        _name(table, f"gateways[{i}]", g)
    for i, r in enumerate(routers):
        _name(table, f"routers[{i}]", r)
    _unique(table, "gateways", gateways)
    _unique(table, "routers", routers)
    subs = table.table("subscribers")
    subscribers = []
    for name in subs.raw:
        _name(subs, name, name)
        entry = subs.table(name, default_empty=False)
        entry.only(("farms", "store"))
        farms = entry.strings("farms")
        if not farms:
            raise entry.fail("farms", "is missing or empty (farm names, or \"*\" for all)")
        for i, farm in enumerate(farms):
            if farm != ALL and farm not in gateways:
                raise entry.fail(f"farms[{i}]", f"= {farm!r} is not in access.gateways "
                                 f"({', '.join(gateways) or 'empty'}); use \"*\" for every farm")
        subscribers.append(Subscriber(name, farms, entry.bool("store", False)))
    clash = (set(gateways) & set(routers)) | (set(gateways) & set(subs.raw)) | (set(routers) & set(subs.raw))
    if clash:
        raise ConfigError(f"{table.source}: access: name(s) {', '.join(sorted(clash))} appear in "
                          "two roles; a certificate name (CN) must identify one role")
    return AccessSpec(gateways, tuple(subscribers), routers, prefix, table.bool("enabled", True))


def _name(table: Table, key: str, value: str) -> None:
    try:
        check_name(value)
    except CertError as exc:
        raise table.fail(key, str(exc).replace("name ", "", 1)) from None


def _unique(table: Table, key: str, values: Iterable[str]) -> None:
    seen: set[str] = set()
    for v in values:
        if v in seen:
            raise table.fail(key, f"lists {v!r} twice")
        seen.add(v)


def access_control(spec: AccessSpec) -> dict[str, Any]:
    """Zenoh's ``access_control`` value for `spec` (default deny)."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    made: set[str] = set()

    def rule(rid: str, farm: str, messages: tuple[str, ...], flow: str) -> str:
        if rid not in made:
            made.add(rid)
            rules.append({"id": rid, "messages": list(messages), "flows": [flow],
                          "permission": "allow", "key_exprs": spec.farm_keys(farm)})
        return rid

    def grant(sid: str, cn: str, rule_ids: list[str]) -> None:
        subjects.append({"id": sid, "cert_common_names": [cn], "link_protocols": ["tls"]})
        policies.append({"id": f"policy:{sid}", "rules": rule_ids, "subjects": [sid]})

    for farm in spec.gateways:
        grant(f"gateway:{farm}", farm, [rule(f"gateway-in:{farm}", farm, GATEWAY_IN, "ingress"),
                                        rule(f"gateway-out:{farm}", farm, GATEWAY_OUT, "egress")])
    for sub in spec.subscribers:
        ids = []
        for farm in sub.farms:
            ids += [rule(f"reader-in:{farm}", farm, READER_IN, "ingress"),
                    rule(f"reader-out:{farm}", farm, READER_OUT, "egress")]
            if sub.store:
                ids += [rule(f"store-in:{farm}", farm, STORE_IN, "ingress"),
                        rule(f"store-out:{farm}", farm, STORE_OUT, "egress")]
        grant(f"subscriber:{sub.name}", sub.name, ids)
    if spec.routers:
        ids = [rule("router-in", ALL, ALL_MESSAGES, "ingress"),
               rule("router-out", ALL, ALL_MESSAGES, "egress")]
        subjects.append({"id": "routers", "cert_common_names": list(spec.routers),
                         "link_protocols": ["tls"]})
        policies.append({"id": "policy:routers", "rules": ids, "subjects": ["routers"]})
    return {"enabled": spec.enabled, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}

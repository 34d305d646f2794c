"""TLS and access control on a real router (``python -m gateway router``) on loopback.

One router for the module: mutual TLS, the fleet's access table, ACL decisions logged. Every
refusal is asserted after a positive control has shown the same path working, and by the
router's own log line (docs/fleet.md shows these lines).
"""

from __future__ import annotations

import re
from collections.abc import Iterator

import pytest
import zenoh

from tests.fleet.conftest import ACCESS
from tests.fleet.kit import (
    Inbox,
    Pki,
    RouterProc,
    client_config,
    open_client,
    stays_false,
    wait_until,
    write_router_toml,
)

QUIET = 1.5  # [s] bounded wait for nothing to arrive, after the positive control arrived
BLOCK = zenoh.CongestionControl.BLOCK


@pytest.fixture(scope="module")
def router(pki: Pki, tmp_path_factory: pytest.TempPathFactory) -> Iterator[RouterProc]:
    folder = tmp_path_factory.mktemp("security")
    config = write_router_toml(folder / "region-1.toml", "region-1", pki, access=ACCESS,
                               log_refusals=True)
    with RouterProc(config) as r:
        yield r
    # __exit__ stopped it with SIGTERM: a clean exit, no hang


def _refused(config: zenoh.Config) -> str:
    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        return str(exc)
    session.close()
    raise AssertionError("the router accepted the session")


def _logged(router: RouterProc, mark: int, pattern: str) -> None:
    wait_until(lambda: re.search(pattern, router.since(mark)), what=f"router log /{pattern}/")


@pytest.mark.parametrize("case, logged", [
    ("no certificate", r"peer sent no certificates"),
    ("another CA", r"invalid peer certificate: (BadSignature|UnknownIssuer)"),
    ("expired", r"invalid peer certificate: certificate expired"),
])
def test_a_client_without_a_valid_certificate_is_refused(case: str, logged: str, pki: Pki,
                                                         other_pki: Pki, router: RouterProc) -> None:
    with open_client(pki, "farm-a", router.endpoints) as ok:  # positive control: same router
        assert [str(z) for z in ok.info.routers_zid()] == [router.zid]
    mark = router.mark()
    if case == "no certificate":
        config = client_config(pki, None, router.endpoints)  # trusts the CA, presents nothing
    elif case == "another CA":  # trusts the fleet CA, presents a farm-a certificate of its own CA
        config = client_config(other_pki, "farm-a", router.endpoints, ca=pki.ca.cert)
    else:
        config = client_config(pki, "farm-old", router.endpoints)
    assert "Unable to connect" in _refused(config)
    _logged(router, mark, logged)


def test_farm_a_cannot_put_under_farm_b(pki: Pki, router: RouterProc) -> None:
    eps = router.endpoints
    mark = router.mark()
    with (open_client(pki, "reader-b", eps) as rb, open_client(pki, "store", eps) as store,
          open_client(pki, "farm-a", eps) as ga, open_client(pki, "farm-b", eps) as gb):
        seen_b, seen_all = Inbox(), Inbox()
        rb.declare_subscriber("serra/farm-b/**", seen_b)
        for key in ("serra/farm-a/**", "serra/farm-b/**"):  # one per farm (AccessSpec.subscriptions)
            store.declare_subscriber(key, seen_all)
        pub_b = gb.declare_publisher("serra/farm-b/gh1/measurement/inside", congestion_control=BLOCK)
        pub_a = ga.declare_publisher("serra/farm-a/gh1/measurement/inside", congestion_control=BLOCK)
        wait_until(lambda: pub_b.matching_status.matching and pub_a.matching_status.matching,
                   what="both gateways' subscribers")
        pub_b.put("b-1")
        pub_a.put("a-1")
        wait_until(lambda: seen_b.has("b-1") and seen_all.has("a-1"), what="positive controls")
        # Farm A's gateway is never told of farm B's subscribers, and a put sent anyway is
        # dropped by the router on arrival (ingress), before anyone can receive it.
        evil = ga.declare_publisher("serra/farm-b/gh1/measurement/inside", congestion_control=BLOCK)
        ga.put("serra/farm-b/gh1/measurement/inside", "a-forged")
        _logged(router, mark, r"CertCommonName\(farm-a\).* is unauthorized to Put \(ingress\) "
                r"on serra/farm-b/gh1/measurement/inside")
        pub_b.put("b-2")
        wait_until(lambda: seen_b.has("b-2"), what="farm B's put after the forged one")
        assert stays_false(lambda: seen_b.has("a-forged") or seen_all.has("a-forged")
                           or evil.matching_status.matching, QUIET)
        assert seen_b.payloads() == ["b-1", "b-2"]


def test_a_subscriber_without_rights_sees_nothing(pki: Pki, router: RouterProc) -> None:
    eps = router.endpoints
    mark = router.mark()
    with (open_client(pki, "stranger", eps) as stranger, open_client(pki, "reader-b", eps) as rb,
          open_client(pki, "reader-a", eps) as ra, open_client(pki, "farm-a", eps) as ga):
        nobody, other_farm, control = Inbox(), Inbox(), Inbox()
        stranger.declare_subscriber("serra/**", nobody)  # a certificate the ACL does not list
        rb.declare_subscriber("serra/farm-a/**", other_farm)  # listed, but for farm B only
        rb.declare_subscriber("serra/**", other_farm)
        ra.declare_subscriber("serra/farm-a/**", control)
        _logged(router, mark, f"{stranger.zid()} did not match any configured ACL subject. "
                "Default permission `Deny`")
        _logged(router, mark, r"CertCommonName\(reader-b\).* is unauthorized to Declare Subscriber "
                r"\(ingress\) on serra/farm-a/\*\*")
        pub = ga.declare_publisher("serra/farm-a/gh1/measurement/inside", congestion_control=BLOCK)
        wait_until(lambda: pub.matching_status.matching, what="reader-a's subscription")
        for i in range(3):
            pub.put(f"a-{i}")
        wait_until(lambda: control.payloads() == ["a-0", "a-1", "a-2"], what="reader-a's data")
        assert stays_false(lambda: nobody.items or other_farm.items, QUIET)


def _answers(session: zenoh.Session, selector: str, timeout: float = 10.0) -> list[str]:
    replies = session.get(selector, consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout)
    return sorted(r.ok.payload.to_string() for r in replies if r.ok is not None)


def test_history_is_answered_only_for_the_own_farm(pki: Pki, router: RouterProc) -> None:
    eps = router.endpoints
    mark = router.mark()
    with (open_client(pki, "store", eps) as store, open_client(pki, "reader-b", eps) as rb,
          open_client(pki, "farm-a", eps) as ga, open_client(pki, "farm-b", eps) as gb):

        def answer(text: str, key: str):
            return lambda q: q.reply(key, text)

        ga.declare_queryable("serra/farm-a/**", answer("a-history", "serra/farm-a/gh1/history/x"))
        ga.declare_queryable("serra/farm-b/**", answer("a-forged", "serra/farm-b/gh1/history/x"))
        gb.declare_queryable("serra/farm-b/**", answer("b-history", "serra/farm-b/gh1/history/x"))
        # positive controls: each farm's history reaches the store through the router
        wait_until(lambda: _answers(store, "serra/farm-a/gh1/history/x") == ["a-history"],
                   what="farm A's history")
        wait_until(lambda: "b-history" in _answers(store, "serra/farm-b/gh1/history/x"),
                   what="farm B's history")
        # farm A's queryable on farm B was refused when declared: only farm B answers
        assert _answers(store, "serra/farm-b/gh1/history/x") == ["b-history"]
        _logged(router, mark, r"CertCommonName\(farm-a\).* is unauthorized to Declare Queryable "
                r"\(ingress\) on serra/farm-b/\*\*")
        # reader-b may query farm B, not farm A (its query is dropped: no answer, bounded wait)
        assert _answers(rb, "serra/farm-b/gh1/history/x") == ["b-history"]
        assert _answers(rb, "serra/farm-a/gh1/history/x", timeout=QUIET) == []
        _logged(router, mark, r"CertCommonName\(reader-b\).* is unauthorized to Query \(ingress\) "
                r"on serra/farm-a/gh1/history/x")

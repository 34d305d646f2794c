"""Fixtures of the fleet tests: one fleet PKI, a stranger CA, and the fleet's access table."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.fleet.kit import Pki, make_pki
from tests.fleet.pg import PgCluster
from tests.fleet.pg import available as pg_available

FARMS = ("farm-a", "farm-b")
ROUTERS = ("cloud", "region-1", "region-2")
ACCESS = {
    "gateways": list(FARMS),
    "routers": list(ROUTERS),
    "subscribers": {
        "store": {"farms": ["*"], "store": True},  # the cloud store: every farm
        "reader-a": {"farms": ["farm-a"]},
        "reader-b": {"farms": ["farm-b"]},
    },
}


@pytest.fixture(scope="session")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Pki]:
    """The fleet CA with certificates for the routers, the gateways (CN = farm), the
    subscribers, a client the access table does not know (stranger) and an expired gateway."""
    p = make_pki(tmp_path_factory.mktemp("pki"), routers=ROUTERS, gateways=FARMS,
                 clients=("store", "reader-a", "reader-b", "stranger"))
    p.add_expired("farm-old")
    yield p


@pytest.fixture(scope="session")
def other_pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    """Another CA that signs a certificate with a valid-looking farm name."""
    return make_pki(tmp_path_factory.mktemp("other-pki"), gateways=("farm-a",))


@pytest.fixture(scope="session")
def pg() -> Iterator[PgCluster]:
    """A throwaway PostgreSQL 15 cluster for the whole session, always stopped after. Tests
    isolate themselves by schema (PgStore.connect(pg.dsn, schema=...))."""
    why = pg_available()
    if why:
        pytest.skip(f"no PostgreSQL cluster: {why}")
    with PgCluster() as cluster:
        yield cluster

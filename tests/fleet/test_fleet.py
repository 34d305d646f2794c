"""The fleet run: 100 simulated gateways (4 processes; each its own SQLite outbox, the real
publisher, a client session with its farm's certificate) → two regional routers → a cloud router
→ the subscriber storing into PostgreSQL. Region-1 is killed (SIGKILL) while the gateways
produce; they go on producing during the outage; it is restarted on its port and they produce
again: the dual-homed gateways fail over to region-2, the single-homed ones hold their messages
in their outboxes and drain them once it is back. On the
PostgreSQL rows: nothing lost, nothing twice, every key in order."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import psycopg
import pytest

from tests.fleet.fleet import Fleet, FleetPlan
from tests.fleet.kit import wait_until
from tests.fleet.pg import PgCluster

PLAN = FleetPlan(gateways=100, procs=4, single_every=10, schema="fleet_test")
RECORDS = 6  # per gateway and phase; two messages each
PACE = 0.1  # [s] between a worker's rounds (one record per gateway each): a phase lasts >= 0.6 s


@pytest.fixture()
def fleet(pg: PgCluster, tmp_path: Path) -> Iterator[Fleet]:
    with Fleet(tmp_path, pg, PLAN) as f:
        yield f
    with psycopg.connect(pg.dsn, autocommit=True) as c:
        c.execute(f"DROP SCHEMA IF EXISTS {PLAN.schema} CASCADE")


def test_a_hundred_gateways_through_two_regions_survive_a_regional_router_crash(fleet: Fleet) -> None:
    fleet.wait_open()
    region1, region2 = fleet.regions
    single = {f for i, f in enumerate(fleet.farms) if i % PLAN.single_every == 0}
    fleet.produce(0, RECORDS, interval=PACE)
    fleet.wait_produced()
    phase1 = fleet.expected_count()
    fleet.wait_stored(phase1)

    port = region1.port
    fleet.produce(RECORDS, 2 * RECORDS, interval=PACE)
    fleet.wait_stored(phase1 + (fleet.expected_count() - phase1) // 10)  # traffic on both regions
    region1.kill()  # mid-run: a crash, nothing closed cleanly
    fleet.wait_produced()

    stuck: list[dict] = []

    def failed_over() -> bool:
        stuck[:] = [g for g in fleet.status() if not (
            g["routers"] == [] if g["farm"] in single
            else g["routers"] == [region2.zid] and g["pending"] == 0)]
        return not stuck

    try:
        wait_until(failed_over, what="the dual-homed gateways on region-2 with empty outboxes, "
                   "the single-homed ones without a router", interval=0.2)
    except AssertionError as e:
        raise AssertionError(f"{e}: {stuck[:5]} (region-2 {region2.zid})") from None
    # the outage goes on: every gateway makes more; the single-homed ones must hold it all
    fleet.produce(2 * RECORDS, 3 * RECORDS, interval=PACE)
    fleet.wait_produced()
    wait_until(lambda: all(g["pending"] == 0 for g in fleet.status() if g["farm"] not in single),
               what="the dual-homed gateways' outboxes drained through region-2", interval=0.2)
    held = {g["farm"]: g["pending"] for g in fleet.status() if g["farm"] in single}
    assert all(n >= 2 * RECORDS for n in held.values()), held  # the outboxes hold
    assert fleet.stored() <= fleet.expected_count() - sum(held.values())

    fleet.regions[0] = fleet.start_region("region-1", port)  # back on its port
    fleet.produce(3 * RECORDS, 4 * RECORDS, interval=PACE)
    fleet.wait_produced()
    fleet.wait_stored(fleet.expected_count())
    finals = fleet.stop_workers()
    assert all(g["pending"] == 0 and not g["error"] for f in finals for g in f["gateways"])

    check = fleet.check()
    assert check.expected == PLAN.gateways * 4 * RECORDS * 2
    assert (check.lost, check.duplicated, check.unexpected) == (0, 0, 0)
    assert check.stored == check.expected
    assert check.out_of_order == [] and check.keys == PLAN.gateways * 2
    assert fleet.subscriber is not None and fleet.subscriber.stop() == 0
    stats = fleet.subscriber_stats()
    print(f"held {sum(held.values())}; subscriber {stats}")
    assert stats["stored"] == check.expected and stats["not_messages"] == 0
    back = {g["farm"]: g["routers"] for f in finals for g in f["gateways"]}
    assert all(back[farm] == [fleet.regions[0].zid] for farm in single)  # reconnected

"""Stress reproducer (not part of `make test`): a cloud subscriber joins while a gateway holds a
60-message backlog on two keys, again and again; counts the runs where the cloud did not get all
60 within 10 s. Run it with the other core busy (`python3 -c 'while 1: pass' &`).

    .venv/bin/python tests/stress/join_race.py --mode cache --runs 500   # the old join: fails
    .venv/bin/python tests/stress/join_race.py --mode live --runs 500    # live samples only
    .venv/bin/python tests/stress/join_race.py --mode subscriber --runs 500  # + the catch-up

``cache`` declares the advanced subscriber with ``HistoryConfig`` as the cloud subscriber did
until 2026-11-24 (docs/cloud.md "Joining while a backlog drains"); ``live`` without it and
without the catch-up; ``subscriber`` is gateway.cloud.subscriber.Subscriber as shipped.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import zenoh
from zenoh.ext import HistoryConfig, RecoveryConfig, declare_advanced_subscriber

from gateway.cloud.store import SqliteCloudStore
from gateway.cloud.subscriber import Subscriber
from gateway.publish import zconfig
from gateway.publish.publisher import OutboxPublisher
from gateway.store import Store
from gateway.store.outbox import Outbox
from tests.gateway_harness import wait_for
from tests.test_publish_zenoh import KEYS, message


class LiveOnly(Subscriber):
    """The advanced subscriber alone (``history``: with the publishers' caches), no catch-up."""

    history_config: HistoryConfig | None = None

    def _declare(self, session) -> None:
        self.session = session
        for key in self.keys:
            sub = declare_advanced_subscriber(session, key, self._on_sample,
                                              history=self.history_config,
                                              recovery=RecoveryConfig(heartbeat=True))
            self.subs.append((sub, sub.sample_miss_listener(self._on_miss)))


class WithCache(LiveOnly):
    history_config = HistoryConfig(detect_late_publishers=True)


def one_run(folder: Path, kind: type[Subscriber]) -> dict[str, list[int]] | None:
    """None when the cloud got all 60, else what it got per key."""
    db = folder / "gw.db"
    store = Store(db)
    for i in range(60):
        Outbox(store.conn).put(message(i))
    before = zconfig.listening_ports()
    session = zenoh.open(zconfig.build(listen=["tcp/127.0.0.1:0"]))
    pub = sub = cloud = None
    try:
        (endpoint,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        pub = OutboxPublisher(session, db, cache=8)
        pub.start()
        wait_for(lambda: len(pub.state.waiting_keys) == 2, 30, "both keys waiting for a subscriber")
        cloud = SqliteCloudStore(folder / "cloud.db")
        sub = kind(cloud, [endpoint])
        sub.start()
        pub.wake.set()
        wait_for(lambda: Outbox(store.conn).pending() == 0, 30, "the backlog marked sent")
        try:
            wait_for(lambda: cloud.count() >= 60, 10, "all 60 in the cloud")
            return None
        except AssertionError:
            pass  # short: report what it has
        return {k: [json.loads(m.payload)["n"] for m in cloud.messages() if m.key == k] for k in KEYS}
    finally:
        for part in (sub, pub):
            if part is not None:
                part.stop()
        session.close()
        store.close()
        if cloud is not None:
            cloud.close()


def main(mode: str, runs: int) -> int:
    kind = {"cache": WithCache, "live": LiveOnly, "subscriber": Subscriber}[mode]
    fails = 0
    for i in range(runs):
        with tempfile.TemporaryDirectory() as d:
            got = one_run(Path(d), kind)
        if got is not None:
            fails += 1
            print(f"run {i}: short: " + ", ".join(f"{k.rsplit('/', 1)[1]} {len(v)} from {v[:1]}"
                                                   for k, v in got.items()), flush=True)
    print(f"{mode}: {fails} of {runs} runs short")
    return fails


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=("cache", "live", "subscriber"), default="subscriber")
    ap.add_argument("--runs", type=int, default=200)
    a = ap.parse_args()
    raise SystemExit(1 if main(a.mode, a.runs) else 0)

"""``make run``'s progress line: its two message counts read from the real stores (the gateway's
outbox, the subscriber's cloud store) while both grow, never show more received than published."""

from __future__ import annotations

import threading
from pathlib import Path

from gateway.cloud.store import Received, SqliteCloudStore
from gateway.store import Store
from gateway.store.outbox import Message, Outbox
from training.appliance.summary import delivery


def test_received_never_reads_above_published_while_both_grow(tmp_path: Path) -> None:
    db, cloud = tmp_path / "serra.db", tmp_path / "cloud.db"
    gateway, sub = Store(db), SqliteCloudStore(cloud)
    outbox = Outbox(gateway.conn)
    total, stop = 400, threading.Event()

    def publish_then_receive() -> None:  # as the run does: put and marked sent, then stored
        for i in range(total):
            if stop.is_set():
                return
            m = Message("serra/f/north/status", "status", float(i), f"idem-{i}", "{}")
            outbox.put(m)
            outbox.mark_sent([r[0] for r in gateway.conn.execute(
                "SELECT id FROM outbox WHERE idem=?", (m.idem,))])
            sub.add([Received(m.key, m.payload, m.idem, "f", "north", m.kind, m.t, m.t)])

    writer = threading.Thread(target=publish_then_receive)
    reads = []
    try:
        writer.start()
        while writer.is_alive():
            reads.append(delivery(db, cloud))
    finally:
        stop.set()
        writer.join(60)
        gateway.close()
        sub.conn.close()
    moving = [r for r in reads if 0 < r[1] < total]
    assert moving, "no read while messages moved (the writer ran too fast to watch)"
    assert all(received <= published for published, received in reads), \
        [r for r in reads if r[1] > r[0]][:5]
    assert delivery(db, cloud) == (total, total)

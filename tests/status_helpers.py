"""What the status tests share besides the ``filled`` and ``store`` fixtures (tests/conftest.py):
snapshots of a store, and status rows written as the running service writes them."""

from __future__ import annotations

import contextlib
import hashlib
import threading
import time
from pathlib import Path

from gateway.status.snapshot import Snapshot
from gateway.status.store_source import StoreSource
from gateway.store import Store
from gateway.store.live import set_status
from tests.status_store import Filled, status_rows


def snap_of(f: Filled, wall: float | None = None) -> Snapshot:
    src = StoreSource(f.path)
    try:
        return src.snapshot(wall=wall)
    finally:
        src.close()


def fresh_status(f: Filled, **kw) -> float:
    """Status rows as a running service writes them; returns their heartbeat."""
    beat = kw.pop("heartbeat", time.time())
    s = Store(f.path)
    try:
        set_status(s.conn, status_rows(f.now, heartbeat=beat, **kw), f.now)
    finally:
        s.close()
    return beat


@contextlib.contextmanager
def beating(f: Filled, every_s: float = 1.0, **kw):
    """Status rows (``status_rows`` options ``kw``) rewritten every ``every_s`` while the block
    runs, as the running service rewrites its own (every 5 s): a command that takes long to start
    on a loaded machine still finds a fresh heartbeat (the staleness limit is 20 s)."""
    stop = threading.Event()

    def beat() -> None:
        while True:
            fresh_status(f, **kw)
            if stop.wait(every_s):
                return

    writer = threading.Thread(target=beat, daemon=True)
    writer.start()
    try:
        yield
    finally:
        stop.set()
        writer.join(30)


def digest(path: Path) -> str:
    return "".join(hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(
        path.parent.glob(path.name + "*")) if not p.name.endswith("-shm"))

"""Snapshot-writes bench: the bytes the live estimator of one greenhouse writes to the store a
day, stepped as live (one batch a minute), side by side for two code trees (e.g. main's and this
one's), in interleaved rounds.

    python tests/bench/snapshot_writes.py --tree out/main-src --tree . [--rounds 2] [--minutes 120]
    # writes bench/results/snapshot_writes.json

Each run is a subprocess importing ``gateway`` from its tree: the real GreenhousePipeline (its
defaults: the tree's snapshot schedule) of a ``biskra-prototype`` greenhouse and the
``prototype+vent_control`` model, with the live estimator budget, on a real SQLite file (WAL,
``synchronous=FULL``, the gateway's ``open_db``). The reference simulator's trace is stored first
(a day and the window), the estimator warms up on the day in catch-up batches (the snapshot's day
buffers fill), then steps ``--minutes`` minutes one batch each, as live. Measured over those
minutes, from ``/proc/self/io`` of the run: ``wchar`` (bytes handed to ``write``: SQLite's WAL
frames and checkpoints) and ``write_bytes`` (bytes the page cache sent towards the disk), scaled
to a day (× 1440 / minutes). The store's other writers (ingest, aggregation, messages) are not in
it: this is the estimator's share. Then, with the checkpoints held off, ``PAGES_MIN`` more minutes
are stepped and the WAL's frames counted by the table or index each page belongs to (``dbstat``):
which pages a minute the estimator writes.
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
WARM_MIN = 1440  # a day: the snapshot's day buffers full
PAGES_MIN = 60  # minutes whose WAL frames are counted by b-tree (four snapshots of 15 minutes)


def _io() -> dict[str, int]:
    with open("/proc/self/io") as f:
        return {k: int(v) for k, v in (line.split(": ") for line in f)}


def _pages_by_btree(conn: Any, wal: Path, work: Any) -> dict[str, int]:
    """WAL frames ``work()`` appends, by the table or index their page belongs to (SQLite's WAL
    format: a 32-byte header, then frames of a 24-byte header, page number first, and a page)."""
    conn.execute("PRAGMA wal_autocheckpoint=0")
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
    work()
    data = wal.read_bytes()
    size = struct.unpack(">I", data[8:12])[0]
    owner = dict(conn.execute("SELECT pageno, name FROM dbstat"))
    counts: dict[str, int] = {}
    for off in range(32, len(data) - size - 23, 24 + size):
        name = owner.get(struct.unpack(">I", data[off:off + 4])[0], "free or new")
        counts[name] = counts.get(name, 0) + 1
    counts["all"] = sum(counts.values())
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def one_run(tree: Path, minutes: int, folder: Path) -> dict[str, Any]:
    """In this process, with ``gateway`` from ``tree`` (sys.path set by the caller)."""
    from dataclasses import replace

    from gateway.greenhouse import load_greenhouse
    from gateway.model import build_model
    from gateway.service.pipeline import GreenhousePipeline
    from gateway.store import Store
    from tests.gateway_harness import EPOCH, sim_trace, store_trace

    gh = load_greenhouse("biskra-prototype")
    model = build_model("prototype+vent_control", gh)
    store = Store(folder / "gw.db")
    total = WARM_MIN + minutes + PAGES_MIN + 1
    store_trace(store, sim_trace(days=total / 1440 + 0.3), range(total))
    pl = GreenhousePipeline("north", replace(gh), model, 7, 7, None)
    pl.resume(store.conn)
    # every record is stored: a minute is final by the clock alone (settle_s past every record)
    settle = 1e12

    def step(k: int) -> None:  # minutes before k are final
        pl.step_pending(store.conn, EPOCH + 60 * k, settle, 0.0)

    t0 = time.perf_counter()
    step(WARM_MIN)
    warm_s = time.perf_counter() - t0
    before, t0 = _io(), time.perf_counter()
    for k in range(WARM_MIN + 1, WARM_MIN + minutes + 1):
        step(k)
    after, live_s = _io(), time.perf_counter() - t0
    assert pl.cursor == EPOCH + 60 * (WARM_MIN + minutes - 1), pl.cursor
    pages = _pages_by_btree(store.conn, folder / "gw.db-wal",
                            lambda: [step(k) for k in range(WARM_MIN + minutes + 1,
                                                            WARM_MIN + minutes + PAGES_MIN + 1)])
    state = store.conn.execute("SELECT state FROM estimator_state").fetchone()[0].encode()
    per_day = 1440 / minutes
    store.close()
    import gateway

    return {"gateway": gateway.__file__, "minutes": minutes, "warm_s": round(warm_s),
            "live_s": round(live_s),
            "wchar_mb_per_day": round((after["wchar"] - before["wchar"]) * per_day / 1e6, 2),
            "write_bytes_mb_per_day": round((after["write_bytes"] - before["write_bytes"])
                                            * per_day / 1e6, 2),
            "pages_per_minute": {k: round(v / PAGES_MIN, 2) for k, v in pages.items()},
            "snapshot_bytes": len(state), "snapshot_zlib6_bytes": len(zlib.compress(state, 6))}


def run(trees: list[Path], rounds: int, minutes: int) -> dict[str, Any]:
    """Interleaved rounds: each round runs every tree once, in a subprocess of its own."""
    runs: dict[str, list[dict[str, Any]]] = {str(t): [] for t in trees}
    for _ in range(rounds):
        for tree in trees:
            with tempfile.TemporaryDirectory(prefix="serra-bench-snap-") as tmp:
                out = subprocess.run(
                    [sys.executable, __file__, "--one", str(tree), "--minutes", str(minutes),
                     "--folder", tmp], check=True, capture_output=True, text=True).stdout
            runs[str(tree)].append(json.loads(out.strip().splitlines()[-1]))
    summary = {}
    for tree, rs in runs.items():
        summary[tree] = {k: sorted(r[k] for r in rs) for k in
                         ("wchar_mb_per_day", "write_bytes_mb_per_day", "snapshot_bytes")}
        summary[tree]["pages_per_minute"] = rs[-1]["pages_per_minute"]
    return {"minutes": minutes, "rounds": rounds, "model": "prototype+vent_control",
            "greenhouse": "biskra-prototype", "runs": runs, "summary": summary}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python tests/bench/snapshot_writes.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", action="append", type=Path,
                        help="a source tree holding gateway/ (repeat: side by side)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--minutes", type=int, default=120, help="minutes stepped as live")
    parser.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # a run, in a subprocess
    parser.add_argument("--folder", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one is not None:
        sys.path.insert(0, str(args.one.resolve()))
        print(json.dumps(one_run(args.one, args.minutes, args.folder)))
        return 0
    sys.path.insert(0, str(HERE))
    from _common import write_result

    trees = args.tree or [ROOT]
    print(write_result("snapshot_writes", run(trees, args.rounds, args.minutes)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

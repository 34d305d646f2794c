"""What counting the records lost on the board (gateway/store/losses.py) costs the store's writer:
``Store.write_batch`` CPU time on this tree against a git commit before it, side by side.

``python tests/bench/losses.py --against REF``: each round runs one process on REF's tree
(``git archive``) and one on this tree, alternately, on one core, with the store not durable
(no fsync: the CPU cost alone, which a durable commit's fsync adds to). Two shapes: ``bulk``, 400
batches of 4 devices x 12 records with a hole every 97 seqs (a backlog arriving); ``live``, 2000
batches of one record (a kit's record a period, as the live gateway sees it). The summary is
the median of the rounds' ratios this tree / REF. Run it under ``nice`` on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, os.environ.get("SERRA_TREE", str(HERE.parents[1])))
from _common import against as against_rounds  # noqa: E402
from _common import one_core, write_result  # noqa: E402

one_core()

from gateway import protocol as p  # noqa: E402
from gateway.store import Store  # noqa: E402

OKV = (21.5, 65.0, 12.0, 80.0, 432.1, 3.4, 0.0)
ROUNDS = 5


def _batches(devices: int, per: int, n: int) -> list[list[tuple[p.Record, float]]]:
    seq = dict.fromkeys(range(7, 7 + devices), 0)
    out = []
    for _ in range(n):
        items = []
        for dev in seq:
            for _ in range(per):
                s = seq[dev]
                seq[dev] += 1
                if s % 97 != 5:
                    items.append((p.Record(dev, 1, s, s * 60_000, 5, 60.0, OKV, (0,) * 7),
                                  1.7e9 + s))
        out.append(items)
    return out


def _cpu_ms(batches: list[list[tuple[p.Record, float]]]) -> float:
    with tempfile.TemporaryDirectory() as d:
        s = Store(Path(d) / "g.db", durable=False)
        t0 = time.process_time()
        for items in batches:
            s.write_batch(items)
        dt = time.process_time() - t0
        s.close()
    return 1000 * dt


def _round() -> dict[str, float]:
    return {"bulk": _cpu_ms(_batches(4, 12, 400)), "live": _cpu_ms(_batches(1, 1, 2000))}


BEFORE = "301f9ba"
"""main's last commit without the count (the merge of fk; dr merged on top of it)."""


def run(against: str) -> dict:
    base, this = against_rounds(__file__, against, ROUNDS)
    keys = list(this[0])
    summary = {f"this_over_{against}_median_of_rounds":
               {k: statistics.median(t[k] / b[k] for t, b in zip(this, base, strict=True))
                for k in keys},
               "cpu_ms_median_of_rounds": {k: statistics.median(t[k] for t in this) for k in keys},
               f"cpu_ms_median_of_rounds_at_{against}":
               {k: statistics.median(b[k] for b in base) for k in keys}}
    return {"rounds": this, f"rounds_at_{against}": base, "summary": summary}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--against", metavar="REF", default=BEFORE,
                        help=f"the git commit to measure against (default {BEFORE}: main just "
                             "before the count; make bench runs it so)")
    parser.add_argument("--round", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.round:  # one round in this process, JSON on the last line (used by --against)
        print(json.dumps(_round()))
        raise SystemExit(0)
    result = run(args.against)
    print(write_result("losses", result))
    print(json.dumps(result["summary"], indent=2))

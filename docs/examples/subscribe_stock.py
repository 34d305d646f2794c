"""Subscribe to a Serra gateway with stock Zenoh only (no Serra code): print each new message,
drop repeats by idempotency key, and ask the gateway for history.

    pip install eclipse-zenoh
    python subscribe_stock.py --connect tcp/192.168.1.20:7447 --key 'serra/**' --count 100
    python subscribe_stock.py --connect tcp/192.168.1.20:7447 \
        --history 'serra/demo-farm/north/history/forecast?from=2026-03-01T00:00:00Z;limit=10'
"""

from __future__ import annotations

import argparse
import json
import threading

import zenoh


def history(session: zenoh.Session, selector: str) -> list[dict]:
    """Every stored message the selector asks for, oldest first. ConsolidationMode.NONE: Zenoh
    would otherwise keep only the latest reply per key."""
    out = []
    for reply in session.get(selector, consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            out.append(json.loads(reply.ok.payload.to_string()))
        else:
            raise ValueError(reply.err.payload.to_string())
    return out


def main(conf: zenoh.Config, key: str = "serra/**", count: int | None = None,
         seconds: float | None = None, history_selector: str | None = None,
         show=print) -> dict[str, dict]:
    """Run until ``count`` new messages arrived or ``seconds`` passed; returns them by key."""
    seen: dict[str, dict] = {}
    lock = threading.Lock()
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        doc = json.loads(sample.payload.to_string())
        idem = doc["idempotencyKey"]["value"]
        with lock:
            if idem in seen:
                return  # a repeat: resent after a gateway restart, or recovered twice
            seen[idem] = doc
            if count is not None and len(seen) >= count:
                done.set()
        show(f"{sample.key_expr} {doc['type']} {idem}")

    with zenoh.open(conf) as session:
        if history_selector:
            for doc in history(session, history_selector):
                show(f"history {doc['type']} {doc['idempotencyKey']['value']}")
        sub = session.declare_subscriber(key, on_sample)
        try:
            done.wait(seconds)
        finally:
            sub.undeclare()  # before the session closes (a declared callback blocks exit)
    return seen


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", action="append", required=True, help="gateway or router endpoint")
    ap.add_argument("--key", default="serra/**")
    ap.add_argument("--count", type=int, help="stop after this many new messages")
    ap.add_argument("--seconds", type=float, help="stop after this long")
    ap.add_argument("--history", help="a history selector to ask first")
    args = ap.parse_args()
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    conf.insert_json5("scouting/multicast/enabled", "false")
    main(conf, args.key, args.count, args.seconds, args.history)

"""Records a board dropped before the gateway stored them, counted per device and boot.

Wire format v1 has no room for the firmware's drop count, but the sequence numbers tell: within
one boot the board numbers its records 0, 1, 2 … (mcu/main.py), and its ring (mcu/ring.py)
drops, when it makes record S, every record with seq ≤ S − 512 (``max_span``) and every record
older than 2**28 ms; a full ring drops its oldest on top of that. Record s's tick is exactly
(S − s) periods before S's (the period ends advance by the period), so "older than 2**28 ms" is
S − s ≥ ⌊2**28 / period_ms⌋ + 1. Once the gateway has received record S, the board has made it,
so every seq ≤ S − span (:func:`span_records`) that is not stored and was not rejected can no
longer arrive: it is final. (The ring's size is not on the wire: a seq a full ring dropped
earlier is counted when the span passes it.) A new boot empties the ring, so every missing seq below the
previous boot's highest stored one is final too (seqs above it are unknowable: not counted).

The accounting runs in the transaction that stores a batch, before its rows are inserted:
each (device, boot) keeps ``final_seq`` in ``boot_losses``, below which every seq is settled,
so a seq is looked at once (an indexed range of ``samples``), never a scan per packet. A record
that still arrives after it was counted (a datagram held in the network) is taken off the count.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable, Mapping
from typing import NamedTuple

RING_MAX_SPAN = 512  # mcu/ring.py: Ring(max_span=512), the firmware never sets another
RING_MAX_AGE_MS = 1 << 28  # mcu/ring.py: _MAX_AGE_MS
RING = "ring"  # dropped from the board's ring (full, or too old)
RESTART = "restart"  # the boot ended (board restarted) before it was resent
ARRIVED = "arrived"  # counted lost, then arrived after all (held in the network)


class Gap(NamedTuple):
    """Seqs ``first``..``last`` of a boot, final and never stored (ARRIVED: seqs counted lost
    that have arrived after all)."""

    device_id: int
    boot: int  # as stored
    first: int
    last: int
    reason: str  # RING, RESTART or ARRIVED

    def __str__(self) -> str:
        return lines([self])[0]


_WHY = {RING: "lost on the board (dropped from its ring: overflow or too old)",
        RESTART: "lost on the board (it restarted before they were stored)",
        ARRIVED: "arrived after being counted lost: no longer counted"}


class BootBatch(NamedTuple):
    """What one batch brings of one (device, boot)."""

    seqs: list[int]
    period_ds: int  # the period on the wire, 0.1 s units


class Report:
    """What a transaction settled: the gaps to log (each once, when whole) and by how much the
    lost counts changed (an arrival of a record counted lost takes it off)."""

    def __init__(self) -> None:
        self.gaps: list[Gap] = []
        self.lost = 0

    def __bool__(self) -> bool:
        return bool(self.gaps or self.lost)


def span_records(period_ds: int) -> int:
    """After the board has made record S, every record ≤ S − span is out of its ring."""
    period_ms = max(period_ds, 1) * 100  # ≤ the board's period_ms: a span never too short
    return min(RING_MAX_SPAN, RING_MAX_AGE_MS // period_ms + 1)


def _ranges(seqs: Iterable[int]) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for s in sorted(seqs):
        if out and s == out[-1][1] + 1:
            out[-1] = (out[-1][0], s)
        else:
            out.append((s, s))
    return out


class _Accounts:
    """The ``boot_losses`` rows: (final_seq, lost, open_from). ``open_from`` is the first seq of
    a missing run that reaches final_seq − 1: counted already, logged once it is whole (the seq
    above it settled as present, or the boot ended), so a long gap is one line, not one per
    record that moved it forward."""

    def __init__(self, conn: sqlite3.Connection, report: Report) -> None:
        self.conn = conn
        self.report = report
        self.rows: dict[tuple[int, int], tuple[int, int, int | None]] = {}

    def row(self, dev: int, boot: int) -> tuple[int, int, int | None]:
        got = self.rows.get((dev, boot))
        if got is None:
            r = self.conn.execute("SELECT final_seq, lost, open_from FROM boot_losses WHERE "
                                  "device_id=? AND boot=?", (dev, boot)).fetchone()
            got = self.rows[(dev, boot)] = (r[0], r[1], r[2]) if r else (0, 0, None)
        return got

    def put(self, dev: int, boot: int, final: int, lost: int, open_from: int | None) -> None:
        self.rows[(dev, boot)] = (final, lost, open_from)
        self.conn.execute("INSERT OR REPLACE INTO boot_losses (device_id, boot, final_seq, lost, "
                          "open_from) VALUES (?, ?, ?, ?, ?)", (dev, boot, final, lost, open_from))

    def settled(self, dev: int, boot: int, lo: int, hi: int) -> set[int]:
        """Seqs in [lo, hi) stored or rejected (primary-key ranges)."""
        args = (dev, boot, lo, hi)
        return {r[0] for r in self.conn.execute(
            "SELECT seq FROM samples WHERE device_id=?1 AND boot=?2 AND seq>=?3 AND seq<?4 UNION ALL "
            "SELECT seq FROM rejected WHERE device_id=?1 AND boot=?2 AND seq>=?3 AND seq<?4",
            args)}

    def settle(self, dev: int, boot: int, upto: int, incoming: Iterable[int],
               ended: bool) -> None:
        """Make every seq below ``upto`` final (``ended``: the boot is over, every run whole);
        the missing ones are counted lost."""
        final, lost, open_from = self.row(dev, boot)
        if upto <= final and not (ended and open_from is not None):
            return
        have = self.settled(dev, boot, final, upto) | {s for s in incoming if final <= s < upto}
        missing = [s for s in range(final, upto) if s not in have]
        runs = _ranges(missing)
        if open_from is not None:
            if runs and runs[0][0] == final:
                runs[0] = (open_from, runs[0][1])
            else:
                runs.insert(0, (open_from, final - 1))
        still = None
        if runs and runs[-1][1] == max(upto, final) - 1 and not ended:
            still = runs.pop()[0]
        # a run settled (in part) while the boot went on was dropped from the ring
        self.report.gaps += [Gap(dev, boot, a, b, RING if a < final or not ended else RESTART)
                             for a, b in runs]
        self.report.lost += len(missing)
        self.put(dev, boot, max(upto, final), lost + len(missing), still)

    def late(self, dev: int, boot: int, seqs: Iterable[int]) -> None:
        """Seqs about to be kept that were counted lost: taken off the count."""
        final, lost, open_from = self.row(dev, boot)
        back = sorted(s for s in set(seqs)
                      if s < final and not self.settled(dev, boot, s, s + 1))
        if not back:
            return
        told = []
        for s in back:
            if open_from is not None and s >= open_from:  # in the run not logged yet
                if s > open_from:
                    self.report.gaps.append(Gap(dev, boot, open_from, s - 1, RING))
                open_from = s + 1 if s + 1 < final else None
            else:
                told.append(s)
        self.report.gaps += [Gap(dev, boot, a, b, ARRIVED) for a, b in _ranges(told)]
        self.report.lost -= len(back)
        self.put(dev, boot, final, lost - len(back), open_from)


def account(conn: sqlite3.Connection, batch: Mapping[int, Mapping[int, BootBatch]],
            report: Report) -> None:
    """Settle the boots a batch touches (device → boot → what it brings), inside the batch's
    transaction and before its rows are inserted (the ``devices`` row still holds the state
    before the batch)."""
    acc = _Accounts(conn, report)
    for dev, boots in batch.items():
        prior = conn.execute("SELECT boot, max_seq FROM devices WHERE device_id=?",
                             (dev,)).fetchone()
        latest = max([*boots, *([prior[0]] if prior else [])])
        for boot, b in boots.items():
            acc.late(dev, boot, b.seqs)
        # Boots that ended: everything below their highest seq is final.
        ended = {boot: max(b.seqs) for boot, b in boots.items() if boot < latest}
        if prior and prior[0] < latest:
            ended[prior[0]] = max(prior[1], ended.get(prior[0], -1))
        for boot in sorted(ended):
            acc.settle(dev, boot, ended[boot] + 1, boots.get(boot, BootBatch([], 0)).seqs, True)
        cur = boots.get(latest)
        if cur is not None:
            top = max(cur.seqs)
            if prior and prior[0] == latest:
                top = max(top, prior[1])
            acc.settle(dev, latest, top - span_records(cur.period_ds) + 1, cur.seqs, False)


def note_rejected(conn: sqlite3.Connection, dev: int, boot: int, seq: int, reason: str,
                  t_recv: float, report: Report) -> None:
    """Keep a record acknowledged as rejected (the board drops it): not a loss."""
    _Accounts(conn, report).late(dev, boot, (seq,))
    conn.execute("INSERT OR IGNORE INTO rejected (device_id, boot, seq, reason, t_recv) VALUES "
                 "(?, ?, ?, ?, ?)", (dev, boot, seq, reason, t_recv))


def lines(gaps: Iterable[Gap], most: int = 4) -> list[str]:
    """One log line per (device, boot, reason), e.g. ``device 7 boot 3: records 1200–1349
    lost on the board (dropped from its ring: overflow or too old)``; past ``most`` ranges,
    how many more and the total."""
    groups: dict[tuple[int, int, str], list[Gap]] = {}
    for g in gaps:
        groups.setdefault((g.device_id, g.boot, g.reason), []).append(g)
    out = []
    for (dev, boot, reason), gs in groups.items():
        n = sum(g.last - g.first + 1 for g in gs)
        seqs = ", ".join(f"{g.first}" + (f"–{g.last}" if g.last > g.first else "")
                         for g in gs[:most])
        if len(gs) > most:
            seqs += f" and {len(gs) - most} more ranges, {n} records in all"
        out.append(f"device {dev} boot {boot}: record{'s' if n > 1 else ''} {seqs} "
                   f"{_WHY.get(reason, reason)}")
    return out


def lost_by_device(conn: sqlite3.Connection) -> dict[int, int]:
    """device → records lost on the board, all boots."""
    try:
        rows = conn.execute("SELECT device_id, sum(lost) FROM boot_losses GROUP BY device_id")
        return {d: int(n) for d, n in rows}
    except sqlite3.OperationalError:  # a reader of a version-2 store: nothing counted yet
        return {}

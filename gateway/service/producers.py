"""Stored rows → outbox messages (the transactional outbox).

Each producer reads what was stored after its cursor (a ``meta`` row), builds the payloads
outside any transaction, then in one short transaction adds the messages and moves the cursor:
a crash leaves both or neither, so no message is lost or made twice. When the outbox is full
(:class:`OutboxFull`) the transaction rolls back and the cursor stays: production resumes when
the publisher has drained, nothing is dropped (the rows wait in their own tables).

- measurements: every kit record → ``measurement/inside`` and/or ``measurement/outside`` of each
  greenhouse that uses the kit;
- estimates: each greenhouse-minute's rows → ``forecast``, ``parameters``, ``fluxes``,
  ``ventilation``;
- findings: a new revision of a finding → ``finding`` (once per revision);
- diagnosis runs: a greenhouse's last run as the scheduler keeps it (gateway/service/diagnosis.py,
  ``meta`` ``diagnosis_run/<greenhouse>``) → ``diagnosis`` (once per run);
- snapshots (every ``status_every_s``, skipped when the outbox has no room: they are state, not
  events): ``status`` (AgriGreenhouse) per greenhouse, ``device/<id>`` per kit.
"""

from __future__ import annotations

import itertools
import logging
import sqlite3
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from gateway.model.model import Model
from gateway.protocol import CHANNELS
from gateway.publish import keyspace as K
from gateway.publish import payloads as P
from gateway.service.diagnosis import RUN_META, read_run
from gateway.store.board_health import board_fields
from gateway.store.db import transaction
from gateway.store.live import device_health, findings
from gateway.store.outbox import Message, Outbox, OutboxFull

log = logging.getLogger("serra.gateway")
SILENT_S = 300.0
"""A kit whose last record is older than this [s, gateway clock] is reported ``silent``."""
PUB_RUN = "pub_diagnosis_run/"
"""``meta`` name prefix of the cursor of a greenhouse's ``diagnosis`` messages: the kept run
(its ``diagnosis_run/<greenhouse>`` value) last made into a message."""


@dataclass(frozen=True)
class GreenhouseInfo:
    place: P.Place
    inside: int
    outside: int
    model: Model
    lower: Sequence[float]
    upper: Sequence[float]


@dataclass
class ProducerCounts:
    made: dict[str, int] = field(default_factory=dict)  # messages per kind
    full: int = 0  # rounds that found the outbox full
    unassigned: set[int] = field(default_factory=set)  # kits in no greenhouse (reported)


class Producers:
    def __init__(self, conn: sqlite3.Connection, farm: str, greenhouses: Mapping[str, GreenhouseInfo],
                 outbox: Outbox, diagnosis: bool = True) -> None:
        """``diagnosis``: publish the diagnosis runs (False: the diagnosis is switched off, and
        a run kept from before is not news)."""
        self.conn, self.farm, self.gh, self.outbox = conn, farm, dict(greenhouses), outbox
        self.publish_runs = diagnosis
        self.counts = ProducerCounts()
        self.roles: dict[int, list[tuple[str, str]]] = {}  # device → [(greenhouse, side)]
        for name, g in self.gh.items():
            self.roles.setdefault(g.inside, []).append((name, "inside"))
            self.roles.setdefault(g.outside, []).append((name, "outside"))
        self.last_snapshot = -float("inf")
        for cursor, table in (("pub_samples_rowid", "samples"), ("pub_estimates_id", "estimates")):
            if self._cursor(cursor) is None:  # first run: what was stored before is not news
                top = conn.execute(f"SELECT coalesce(max(rowid), 0) FROM {table}").fetchone()[0]
                self._commit([], {cursor: top})
                if top:
                    log.info("publishing starts after the %d rows already in %s", top, table)

    # -- plumbing ---------------------------------------------------------------------------
    def _cursor(self, name: str) -> int | None:
        r = self.conn.execute("SELECT value FROM meta WHERE name=?", (name,)).fetchone()
        return int(r[0]) if r else None

    def _commit(self, msgs: list[Message], cursors: Mapping[str, int],
                extra: Sequence[tuple[str, tuple]] = ()) -> int:
        """Add ``msgs`` and move the cursors in one transaction. Returns how far the producer got:
        the number of messages (at least 1 when rows were consumed), -1 when the outbox is full."""
        try:
            with transaction(self.conn):
                self.outbox.add(msgs)
                for name, value in cursors.items():
                    self.conn.execute("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)",
                                      (name, str(value)))
                for sql, args in extra:
                    self.conn.execute(sql, args)
        except OutboxFull:
            self.counts.full += 1
            return -1
        for m in msgs:
            self.counts.made[m.kind] = self.counts.made.get(m.kind, 0) + 1
        return max(len(msgs), 1)

    def _msg(self, greenhouse: str, kind: str, t: float, idem: str, payload: dict) -> Message:
        return Message(K.key(self.farm, greenhouse, kind), kind, t, idem, P.dumps(payload))

    def run(self, limit: int = 500) -> int:
        """All event producers until caught up or the outbox is full; messages made."""
        total = 0
        for produce in (self.measurements, self.estimates, self.findings, self.diagnosis_runs):
            while (n := produce(limit)) > 0:
                total += n
            if n < 0:
                break  # full: stop this round
        return total

    # -- measurements -------------------------------------------------------------------------
    def measurements(self, limit: int) -> int:
        """Returns messages made, 0 when caught up, -1 when the outbox is full."""
        cur = self._cursor("pub_samples_rowid") or 0
        cols = ", ".join(f"{c}, {c}_st" for c in CHANNELS)
        rows = self.conn.execute(f"SELECT rowid, device_id, boot, seq, t, {cols} FROM samples "
                                 "WHERE rowid>? ORDER BY rowid LIMIT ?", (cur, limit)).fetchall()
        if not rows:
            return 0
        room = self.outbox.room()
        msgs: list[Message] = []
        last = None
        for r in rows:
            made = self._reading_messages(r)
            if len(msgs) + len(made) > room:
                break  # the rest waits for room: the cursor stops before this record
            msgs += made
            last = r[0]
        if last is None:
            self.counts.full += 1
            return -1
        return self._commit(msgs, {"pub_samples_rowid": last})

    def _reading_messages(self, r: tuple) -> list[Message]:
        dev, boot, seq, t = r[1:5]
        roles = self.roles.get(dev)
        if not roles:
            self.counts.unassigned.add(dev)  # reported by the worker (and device snapshots)
            return []
        ch = {c: (r[5 + 2 * i], r[6 + 2 * i]) for i, c in enumerate(CHANNELS)}
        reading = P.Reading(dev, boot, seq, t, ch)
        out = []
        for gh, side in roles:
            kind = f"measurement/{side}"
            idem = f"{self.farm}/{gh}/{kind}/{dev}/{boot}/{seq}"
            out.append(self._msg(gh, kind, t, idem,
                                 P.weather_observed(self.gh[gh].place, side, reading, idem)))
        return out

    # -- estimates ------------------------------------------------------------------------------
    def estimates(self, limit: int) -> int:
        cur = self._cursor("pub_estimates_id") or 0
        rows = self.conn.execute(
            "SELECT id, greenhouse, t, source, name, value, unit, info FROM estimates "
            "WHERE id>? ORDER BY id LIMIT ?", (cur, limit * 40)).fetchall()
        if not rows:
            return 0
        groups = [list(g) for _, g in itertools.groupby(rows, key=lambda r: (r[1], r[2]))]
        if len(rows) == limit * 40 and len(groups) > 1:
            groups.pop()  # may be cut by the limit: next round
        room = self.outbox.room()
        msgs: list[Message] = []
        last = None
        for g in groups:
            made = self._estimate_messages(g)
            if len(msgs) + len(made) > room:
                break
            msgs += made
            last = g[-1][0]
        if last is None:
            self.counts.full += 1
            return -1
        return self._commit(msgs, {"pub_estimates_id": last})

    def _estimate_messages(self, rows: list[tuple]) -> list[Message]:
        gh, t = rows[0][1], rows[0][2]
        info = self.gh.get(gh)
        if info is None:
            return []  # a greenhouse no longer in the config
        by = {(r[3], r[4]): r for r in rows}
        minute = int(t)
        out = []
        place, model = info.place, info.model
        fc = sorted((int(name[5:-3]), r[5]) for (src, name), r in by.items()
                    if src == "forecast" and r[5] is not None)
        measured = by.get(("measured", "t_in"))
        if fc and measured is not None:
            outlook = next(r[7] for (src, _), r in by.items() if src == "forecast")
            idem = f"{self.farm}/{gh}/forecast/{minute}"
            out.append(self._msg(gh, "forecast", t, idem, P.forecast(
                place, t, idem, model=model.name, outlook=outlook, t_in=measured[5], horizons=fc)))
        values = [P.ParameterValue(p.name, by[("online", p.name)][5], p.unit, lo, hi)
                  for p, lo, hi in zip(model.parameters, info.lower, info.upper, strict=True)
                  if ("online", p.name) in by]
        if values:
            idem = f"{self.farm}/{gh}/parameters/{minute}"
            out.append(self._msg(gh, "parameters", t, idem,
                                 P.parameters(place, t, idem, model=model.name, values=values)))
        flux = {name: r[5] for (src, name), r in by.items() if src == "flux" and r[5] is not None}
        if flux:
            idem = f"{self.farm}/{gh}/fluxes/{minute}"
            out.append(self._msg(gh, "fluxes", t, idem,
                                 P.fluxes(place, t, idem, model=model.name, values=flux)))
        flow, loss = by.get(("vsensor", "ventilation_flow")), by.get(("vsensor", "ventilation_heat_loss"))
        if flow is not None and loss is not None and flow[5] is not None and loss[5] is not None:
            idem = f"{self.farm}/{gh}/ventilation/{minute}"
            out.append(self._msg(gh, "ventilation", t, idem, P.ventilation(
                place, t, idem, flow=flow[5], heat_loss=loss[5], out_of_range=flow[7] == "out_of_range")))
        return out

    # -- findings -------------------------------------------------------------------------------
    def findings(self, limit: int) -> int:
        todo = [f for f in findings(self.conn) if f.revision > f.published_revision][:limit]
        if not todo:
            return 0
        msgs, extra = [], []
        for f in todo:
            info = self.gh.get(f.greenhouse)
            if info is not None:
                idem = f"{self.farm}/{f.greenhouse}/finding/{f.id}/r{f.revision}"
                msgs.append(self._msg(f.greenhouse, "finding", f.last_seen, idem, P.finding(
                    info.place, idem, finding_id=f.id.split(":", 1)[-1], effect=f.effect,
                    start=f.start, first_seen=f.first_seen, last_seen=f.last_seen,
                    revision=f.revision, detail=f.detail)))
            extra.append(("UPDATE findings SET published_revision=? WHERE id=?", (f.revision, f.id)))
        return self._commit(msgs, {}, extra)

    # -- diagnosis runs -------------------------------------------------------------------------
    def diagnosis_runs(self, limit: int) -> int:
        """Each greenhouse's last diagnosis run not yet published → ``diagnosis``, made in the
        transaction that moves its cursor (:data:`PUB_RUN`). A kept run that cannot be read is
        passed over (a warning, once: the cursor moves past it)."""
        if not self.publish_runs:
            return 0
        kept = dict(self.conn.execute("SELECT name, value FROM meta WHERE name GLOB ?",
                                      (RUN_META + "*",)).fetchall())
        done = dict(self.conn.execute("SELECT name, value FROM meta WHERE name GLOB ?",
                                      (PUB_RUN + "*",)).fetchall())
        msgs, extra = [], []
        for name, info in list(self.gh.items())[:limit]:
            value = kept.get(RUN_META + name)
            if value is None or done.get(PUB_RUN + name) == value:
                continue
            extra.append(("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)",
                          (PUB_RUN + name, value)))
            try:
                run = read_run(name, value)
            except ValueError as e:
                log.warning("greenhouse %s: the kept diagnosis run is not published, it cannot "
                            "be read: %s", name, e)
                continue
            idem = f"{self.farm}/{name}/diagnosis/{int(run.when)}"
            msgs.append(self._msg(name, "diagnosis", run.when, idem, P.diagnosis_run(
                info.place, idem, when=run.when, ok=run.ok, note=run.note,
                findings=run.findings, notes=run.notes)))
        if not extra:
            return 0
        return self._commit(msgs, {}, extra)

    # -- snapshots ------------------------------------------------------------------------------
    def snapshots(self, now: float, every_s: float, state: Mapping[str, Mapping[str, Any]]) -> int:
        """``status`` per greenhouse and ``device/<id>`` per kit, every ``every_s``; ``state``:
        greenhouse → extra status attributes (estimator state, outbox, link)."""
        if now - self.last_snapshot < every_s:
            return 0
        health = {h.device_id: h for h in device_health(self.conn)}
        msgs = []
        stamp = int(now)
        for name, info in self.gh.items():
            latest = self.conn.execute(
                "SELECT t_in, rh_in FROM samples WHERE device_id=? ORDER BY boot DESC, seq DESC "
                "LIMIT 1", (info.inside,)).fetchone()
            idem = f"{self.farm}/{name}/status/{stamp}"
            msgs.append(self._msg(name, "status", now, idem, P.agri_greenhouse(
                info.place, now, [info.inside, info.outside], idem,
                rh_in=latest[1] if latest else None, t_in=latest[0] if latest else None,
                state=state.get(name, {}))))
        for dev in sorted(set(health) | set(self.roles)):
            h = health.get(dev)
            ghs = sorted({g for g, _ in self.roles.get(dev, [])})
            if not ghs:
                run = "unassigned"
            elif h is None or h.last_sample_t is None or now - h.last_sample_t > SILENT_S:
                run = "silent"
            else:
                run = "ok"
            for gh in ghs or [K.UNASSIGNED]:
                kind = K.device_kind(dev)
                idem = f"{self.farm}/{gh}/{kind}/{stamp}"
                msgs.append(self._msg(gh, kind, now, idem, P.device(
                    self.farm, dev, now, idem, state=run, boot=h.boot if h else None,
                    records=h.records if h else 0, last_seen=h.last_sample_t if h else None,
                    channels=h.channels if h else {},
                    greenhouses=[self.gh[g].place for g in ghs],
                    board_boot=h.board_boot if h else None, lost=h.lost if h else 0,
                    board=board_fields(h.board, h.boot, h.board_boot) if h and h.board else None)))
        if len(msgs) > self.outbox.room():
            return 0  # state, not events: skipped while the backlog drains
        self.last_snapshot = now
        return max(self._commit(msgs, {}), 0)


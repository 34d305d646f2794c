"""The daily diagnosis, in a separate process, and its findings with a stable identity.

Every ``every_hours`` (gateway clock) each greenhouse's last ``days`` of minutes are written as a
kit CSV and handed to ``python -m gateway diagnose --json`` (the diagnosis's own entry point; a
greenhouse running ``prototype+vent_control`` or its heated variant is diagnosed with
``--model prototype``, whose base chooses the vent controller part for itself:
``diagnose_command``) in a subprocess at low priority, so ingest and the estimators never wait
for it. Its findings are stored under a stable identity: a finding of the same effect in the same
greenhouse whose start is within ``MATCH_S`` of a known one *is* that one (a daily re-run moves
the estimated start a little); it is published again only when it changed (start moved by more
than ``MOVE_S`` or amplitude by more than ``CHANGE_REL``), as a new revision, never re-announced
daily. Each greenhouse's last run (time, outcome, summary, notes) is kept in the store's ``meta``
(:data:`RUN_META`), so the status shows it again right after a restart, and published once as a
``diagnosis`` message (gateway/service/producers.py), so a screen reading the gateway over Zenoh
shows it too.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
import sqlite3
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gateway.kitcsv import write_kit_csv
from gateway.model import PROTOTYPES
from gateway.service.diagnosis_hold import RoundHold, settled
from gateway.service.findings import merge_findings
from gateway.service.minutes import KIT_COLUMNS, read_minutes
from gateway.service.resources import GreenhouseResources
from gateway.service.settings import GatewayConfig, GreenhouseSettings
from gateway.store.db import open_db, transaction
from gateway.store.outage import Outage

log = logging.getLogger("serra.gateway")


EXPORT_PART_S = 86400
"""The export reads and writes a day of minutes at a time: the gateway's heap keeps its
high-water mark, and the whole window at once (10 days, ~16 MB of Python objects) stepped its
RSS up by ~2 MB a day exported (tests/bench/soak.py, docs/gateway.md "Over many days")."""


def export_window(conn: sqlite3.Connection, r: GreenhouseResources, start: float, end: float,
                  path: Path) -> int:
    """The greenhouse's minutes in [start, end) as a kit CSV (QC-dropped values empty), written
    a part of :data:`EXPORT_PART_S` at a time; the number of minutes (0: no file written)."""
    s, n = r.settings, 0
    with path.open("w", newline="", encoding="utf-8") as f:
        for lo in range(int(start), int(end), EXPORT_PART_S):
            minutes = read_minutes(conn, s.inside, s.outside, lo, min(lo + EXPORT_PART_S, int(end)))
            if not minutes:
                continue
            t = np.array([m.minute for m in minutes], dtype="int64").astype("datetime64[s]")
            cols = {c: np.array([m.values[c] for m in minutes], dtype=float) for c in KIT_COLUMNS}
            write_kit_csv(f, t, cols, header=n == 0)
            n += len(minutes)
    if n == 0:
        path.unlink()
    return n


def diagnose_command(g: GreenhouseSettings, data: Path) -> list[str]:
    """``gateway diagnose`` on a greenhouse's exported minutes, with its model, except that a
    greenhouse running the vented prototype is diagnosed as the prototype: its base chooses the
    vent controller part for itself (gateway/diagnose/base.py ``options``, on its inner validation
    split), as the diagnosis was tuned and measured (the generality suite's diagnosis cases)."""
    model = "prototype" if g.model in PROTOTYPES else g.model  # as the diagnosis was tuned
    return [sys.executable, "-m", "gateway", "diagnose", "--data", str(data), "--greenhouse",
            g.greenhouse, "--model", model, "--json"]


def diagnose_result(out: bytes) -> dict[str, Any]:
    """``diagnose --json``'s stdout as the scheduler reads it: a JSON object whose
    ``findings`` is a list of objects each naming its ``effect`` and whose ``notes``, when
    given, a list of objects. ValueError saying what is wrong (anything else on stdout, say a
    library's message, would otherwise end the scheduler's task and with it the gateway)."""
    try:
        result = json.loads(out)
    except ValueError as e:  # JSONDecodeError, bytes that are not UTF-8
        first = out.decode(errors="replace").strip().splitlines()[:1] or ["nothing"]
        raise ValueError(f"not JSON ({e}; it begins {first[0][:60]!r})") from None
    if not isinstance(result, dict):
        raise ValueError(f"a JSON object expected, got {type(result).__name__}")
    found = result.get("findings")
    if not isinstance(found, list) or not all(isinstance(f, dict) and "effect" in f
                                              for f in found):
        raise ValueError("no list of findings each naming its effect")
    notes = result.get("notes", [])
    if not isinstance(notes, list) or not all(isinstance(n, dict) for n in notes):
        raise ValueError("its notes are not a list of {code, level, message} objects")
    return result


def model_hint_notes(running: str, result: dict[str, Any]) -> list[dict[str, str]]:
    """diagnose's hint (its JSON's ``hint``, ``hint_model``) as a run's note, when it names a
    model other than the one the greenhouse's estimator runs (``running``): the diagnosis runs
    as ``prototype`` whatever prototype the gateway runs, so its vent-controller hint to a
    gateway already on the vented (or heated) model says nothing new."""
    from gateway.model import HEATED_PROTOTYPE, VENTED_PROTOTYPE

    model, hint = result.get("hint_model"), result.get("hint")
    carried = {VENTED_PROTOTYPE: (VENTED_PROTOTYPE, HEATED_PROTOTYPE),
               HEATED_PROTOTYPE: (HEATED_PROTOTYPE,)}
    if not model or not hint or running in carried.get(model, (model,)):
        return []
    return [{"code": "model_hint", "level": "note", "message": hint}]


def named_data(notes: list[dict[str, Any]], path: Path, label: str) -> list[dict[str, Any]]:
    """The diagnosis's notes with the exported CSV's path (a file in the gateway's work folder,
    gone after the run) replaced by ``label``, what the data is to a grower and the cloud."""
    return [{**n, "message": n["message"].replace(str(path), label)}
            if isinstance(n, dict) and isinstance(n.get("message"), str) else n for n in notes]


def _save_last(conn: sqlite3.Connection, t: float) -> None:
    conn.execute("INSERT OR REPLACE INTO meta (name, value) VALUES ('diagnosis_last', ?)", (repr(t),))


@dataclass
class DiagnosisRun:
    """One greenhouse's latest run, as the gateway's status says it (``gateway_status``, row
    ``diagnosis``). ``when``: gateway clock [unix s]. ``notes``: what diagnose said of the data
    beside its findings, its JSON's ``{code, level, message}`` records as given
    (gateway/cli/notes.py: data_gaps, site_time_mismatch, short_heldout, …)."""

    greenhouse: str
    when: float
    ok: bool
    note: str
    findings: int = 0
    notes: list[dict[str, str]] = field(default_factory=list)

    def row(self) -> dict[str, Any]:
        """The run as the status row (and the store's ``meta``) hold it."""
        return {"when": self.when, "ok": self.ok, "note": self.note, "findings": self.findings,
                "notes": self.notes}


RUN_META = "diagnosis_run/"
"""``meta`` name prefix of a greenhouse's last run (``diagnosis_run/<greenhouse>``, JSON of
:meth:`DiagnosisRun.row`): the status shows it again right after a restart."""


def save_run(conn: sqlite3.Connection, run: DiagnosisRun) -> None:
    """Keep ``run`` as its greenhouse's last run (replacing the one before)."""
    conn.execute("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)",
                 (RUN_META + run.greenhouse, json.dumps(run.row())))


def keep_run(conn: sqlite3.Connection, run: DiagnosisRun, found: list[dict[str, Any]],
             last: float | None) -> list[str]:
    """A run's findings, the run and (``last``, the round's time, with its last greenhouse) the
    round, in one transaction: a store failing meanwhile leaves none of them half-written.
    Returns a line per new or changed finding."""
    with transaction(conn):
        notes = merge_findings(conn, run.greenhouse, found, run.when)
        save_run(conn, run)
        if last is not None:
            _save_last(conn, last)
    return notes


def read_run(greenhouse: str, value: str) -> DiagnosisRun:
    """A stored run back; ValueError saying what is wrong with it. A note kept before the
    status row named the greenhouse itself ("greenhouse north: diagnosis of …") loses that
    prefix, so the row does not say the name twice."""
    try:
        d = json.loads(value)
    except json.JSONDecodeError as e:
        raise ValueError(f"not JSON ({e})") from None
    if not isinstance(d, dict):
        raise ValueError(f"a JSON object expected, got {type(d).__name__}")
    kinds = {"when": ((int, float), "a number"), "ok": ((bool,), "true or false"),
             "note": ((str,), "a string"), "findings": ((int,), "a whole number"),
             "notes": ((list,), "a list")}
    for key, (types, what) in kinds.items():
        v = d.get(key)
        if not isinstance(v, types) or (key != "ok" and isinstance(v, bool)):
            raise ValueError(f"key {key!r}: {v!r} is not {what}")
    try:
        when = float(d["when"])
    except OverflowError:  # an integer of hundreds of digits
        when = math.inf
    if not math.isfinite(when):
        raise ValueError(f"key 'when': {d['when']!r} is not a finite number")
    if not all(isinstance(n, dict) for n in d["notes"]):
        raise ValueError("key 'notes': every note must be a {code, level, message} object")
    note = d["note"].removeprefix(f"greenhouse {greenhouse}: ")
    return DiagnosisRun(greenhouse, when, d["ok"], note, d["findings"],
                        list(d["notes"]))


def load_runs(conn: sqlite3.Connection, greenhouses: list[str], where: str = "store"
              ) -> dict[str, DiagnosisRun]:
    """The last run kept of each of ``greenhouses`` (those never run are absent). A stored run
    that cannot be read is logged as a warning naming ``where`` and the ``meta`` row, and left
    out: the status shows no row for it until its next run."""
    out = {}
    for name in greenhouses:
        r = conn.execute("SELECT value FROM meta WHERE name=?", (RUN_META + name,)).fetchone()
        if r is None:
            continue
        try:
            out[name] = read_run(name, r[0])
        except ValueError as e:
            log.warning("%s: meta %s%s: not a diagnosis run, ignored: %s", where, RUN_META, name, e)
    return out


class DiagnosisScheduler:
    """The asyncio task that runs the diagnosis on schedule (``run_forever``). Each run is kept
    in the store as its greenhouse's last (:func:`save_run`) and read back when the scheduler is
    made, so the status has each greenhouse's last run from the start (``last``); the worker
    publishes each kept run once (kind ``diagnosis``)."""

    def __init__(self, cfg: GatewayConfig, resources: list[GreenhouseResources],
                 clock: Callable[[], float], workdir: Path, on_stored: Callable[[], None],
                 outage: Outage | None = None) -> None:
        """``on_stored``: called after each run is kept (with its findings), so the worker makes
        their messages (``finding``, ``diagnosis``: gateway/service/producers.py); ``outage``:
        the service's, told of a store that cannot be written (the round waits it out:
        gateway/service/diagnosis_hold.py)."""
        self.cfg, self.resources, self.clock = cfg, resources, clock
        self.workdir, self.on_stored = workdir, on_stored
        self.hold = RoundHold(outage or Outage(cfg.db, "the diagnosis waits"))
        self.last: dict[str, DiagnosisRun] = self._kept()
        self.proc: asyncio.subprocess.Process | None = None

    def _kept(self) -> dict[str, DiagnosisRun]:
        """Each greenhouse's last run as the store keeps it (before a restart, say)."""
        conn = open_db(self.cfg.db)
        try:
            return load_runs(conn, [r.settings.name for r in self.resources], str(self.cfg.db))
        finally:
            conn.close()

    def status(self) -> dict[str, Any]:
        return {g: r.row() for g, r in self.last.items()}

    async def run_forever(self, tick: float = 5.0) -> None:
        conn = await settled(open_db, self.cfg.db)
        try:
            row = await self.hold.store(
                lambda: conn.execute("SELECT value FROM meta WHERE name='diagnosis_last'").fetchone())
            last = float(row[0]) if row else None
            if last is None:  # first start: the first run comes one period from now
                last = self.clock()
                await self.hold.store(_save_last, conn, last)
            while True:
                now = self.clock()
                if now - last >= self.cfg.diagnosis.every_hours * 3600:
                    await self._round(conn, now)
                    last = now
                await asyncio.sleep(tick)
        finally:
            conn.close()

    async def _round(self, conn: sqlite3.Connection, now: float) -> None:
        """Each greenhouse's run, kept as it ends; the round's time with the last one."""
        if not self.resources:
            await self.hold.store(_save_last, conn, now)
        for i, r in enumerate(self.resources):
            run, found = await self.run_one(conn, r, now)
            last = now if i == len(self.resources) - 1 else None
            held = f"greenhouse {r.settings.name}: the diagnosis run ({run.note})"
            for n in await self.hold.store(keep_run, conn, run, found, last, held=held):
                log.info(n)
            self.last[r.settings.name] = run
            self.on_stored()  # its findings and the run itself: messages to make

    async def run_one(self, conn: sqlite3.Connection, r: GreenhouseResources, now: float
                      ) -> tuple[DiagnosisRun, list[dict[str, Any]]]:
        """A greenhouse's run and its findings (for :func:`keep_run`)."""
        d, name = self.cfg.diagnosis, r.settings.name
        path = self.workdir / f"diagnosis-{name}.csv"
        rows = await self.hold.data(name, path, export_window, conn, r, now - d.days * 86400,
                                    now, path)
        if rows < d.min_days * 1440:
            note = f"diagnosis skipped, {rows / 1440:.1f} days of data (needs {d.min_days:g})"
            log.info("greenhouse %s: %s", name, note)
            return DiagnosisRun(name, now, True, note), []
        cmd = diagnose_command(r.settings, path)
        t0 = time.monotonic()
        self.proc = proc = await asyncio.create_subprocess_exec(
            *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
        try:
            os.setpriority(os.PRIO_PROCESS, proc.pid, 10)  # the estimators and ingest come first
        except OSError:
            pass
        try:
            out, err = await asyncio.wait_for(proc.communicate(), d.timeout_s)
        except TimeoutError:
            proc.kill()
            await proc.wait()
            note = f"diagnosis abandoned after {d.timeout_s:g} s"
            log.warning("greenhouse %s: %s", name, note)
            return DiagnosisRun(name, now, False, note), []
        finally:
            self.proc = None
        if proc.returncode != 0:
            msg = err.decode(errors="replace").strip().splitlines()[-1:] or ["no message"]
            note = f"diagnosis failed (exit {proc.returncode}): {msg[0]}"
            log.warning("greenhouse %s: %s", name, note)
            return DiagnosisRun(name, now, False, note), []
        try:
            result = diagnose_result(out)
        except ValueError as e:  # a failed run, as a crash is: the gateway goes on
            note = f"diagnosis output unreadable: {e}"
            log.warning("greenhouse %s: %s", name, note)
            return DiagnosisRun(name, now, False, note), []
        data_notes = (named_data(result.get("notes", []), path, f"{name}'s last {rows / 1440:.1f} days")
                      + model_hint_notes(r.settings.model, result))
        for said in data_notes:  # each once per run; a warning: the figures are likely wrong
            log.log(logging.WARNING if said.get("level") == "warning" else logging.INFO,
                    "greenhouse %s: diagnosis %s: %s [%s]", name, said.get("level", "note"),
                    said.get("message", ""), said.get("code", "?"))
        note = (f"diagnosis of {rows / 1440:.1f} days in {time.monotonic() - t0:.0f} s: "
                f"{len(result['findings'])} finding(s)")
        log.info("greenhouse %s: %s", name, note)
        return (DiagnosisRun(name, now, True, note, len(result["findings"]), data_notes),
                result["findings"])

    def kill(self) -> None:
        if self.proc is not None and self.proc.returncode is None:
            self.proc.kill()


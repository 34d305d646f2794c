"""A :class:`~gateway.status.snapshot.Snapshot` read from the gateway's store, read-only.

The connection is opened with :func:`gateway.store.open_readonly` (SQLite ``mode=ro``, refusing a
file that is not a Serra store), so the screen can never write. Every query is an index seek or a
range of at most a day of rows: a refresh costs the same on a store of one day or of a year.
"""

from __future__ import annotations

import json
import math
import shutil
import sqlite3
import time
from pathlib import Path
from typing import Any

from gateway.protocol import STATUS_NAMES
from gateway.status import snapshot as S
from gateway.store import StoreError, open_readonly
from gateway.store.aggregate import QC_MISSING, QC_SPIKE, QC_STUCK
from gateway.store.board_health import BoardReport
from gateway.store.live import device_health, findings, outbox_backlog, read_status
from gateway.store.outage import LOW_FREE_BYTES

DROP = QC_MISSING | QC_SPIKE | QC_STUCK  # as the export drops them
SIDES = {"inside": ("t_in", "rh_in"), "outside": ("t_out", "rh_out", "i_glob", "wind", "rain")}
SKILL_SPAN = S.DAY


class StoreSource:
    """Snapshots of one store. Raises :class:`gateway.store.StoreError` naming a bad file."""

    def __init__(self, path: str | Path, bins: int = S.FINE_BINS) -> None:
        self.path = Path(path)
        self.bins = bins
        self.conn = open_readonly(self.path)
        version = self.conn.execute("PRAGMA user_version").fetchone()[0]
        if version < 5:  # no estimates_latest yet; a reader cannot migrate
            self.conn.close()
            raise StoreError(f"{self.path}: store schema version {version}: start the gateway "
                             "once to migrate it to version 5 (docs/store.md)")
        self._bounds: dict[str, tuple[list[str], list[float | None], list[float | None]]] = {}
        self._no_sensor: dict[str, str] = {}  # greenhouse → why no shipped sensor fits it

    @property
    def label(self) -> str:
        return f"store {self.path}"

    def close(self) -> None:
        self.conn.close()

    def snapshot(self, wall: float | None = None) -> S.Snapshot:
        wall = time.time() if wall is None else wall
        c = self.conn
        tables = {r[0] for r in c.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        c.execute("BEGIN")  # one consistent view of the WAL for the whole snapshot
        try:
            status = read_status(c) if "gateway_status" in tables else {}
            gw, now, notes = self._gateway(status, wall)
            ghs = self._greenhouses(now) if "greenhouses" in tables else []
            kits = self._kits(now, ghs, status)
        finally:
            c.execute("COMMIT")
        if not ghs:
            notes.append("no greenhouse in this store yet (the gateway writes its config at start; "
                         "an ingest-only store has none)")
        if not kits:
            notes.append("no kit has sent a record yet")
        farm = ghs[0].farm if ghs else str(status.get("gateway", ({}, 0))[0].get("farm", ""))
        return S.Snapshot(self.label, now, wall, farm, tuple(ghs), tuple(kits), gw, tuple(notes))

    # -- the gateway ------------------------------------------------------------------------
    def _gateway(self, status: dict[str, tuple[Any, float]], wall: float
                 ) -> tuple[S.Gateway, float | None, list[str]]:
        notes: list[str] = []
        g = status.get("gateway", ({}, 0.0))[0]
        beat = g.get("heartbeat")
        scale = float(g.get("clock_scale", 1.0))
        age = wall - beat if beat is not None else None
        running = (None if beat is None else  # a clean stop says so; a crash goes stale
                   not g.get("stopped") and age is not None and age < S.HEARTBEAT_STALE_S)
        if beat is None:
            notes.append("no gateway service has run on this store (no heartbeat)")
            now: float | None = self._latest_time() or wall
        elif scale == 1.0:
            now = wall
        elif running:
            now = float(g["clock_now"]) + (wall - beat) * scale
        else:  # a stopped test/demo clock: its time stands where the gateway stopped
            now = float(g["clock_now"])
        if running is False:
            notes.append(f"the gateway is not running: last heartbeat {_ago(age)} ago")
        notes += _store_notes(status.get("store", ({}, 0.0))[0], running, self._disk(), wall)
        z = status.get("zenoh", ({}, 0.0))[0]
        ob = status.get("outbox", ({}, 0.0))[0]
        pending, oldest = outbox_backlog(self.conn)
        alarm_at = ob.get("alarm_at")
        outbox = S.Outbox(pending, ob.get("max"), alarm_at,
                          bool(alarm_at is not None and pending >= alarm_at), oldest)
        diag = {name: S.diagnosis_of(d) for name, d in
                status.get("diagnosis", ({}, 0.0))[0].items() if isinstance(d, dict)}
        refused = status.get("refused", ({}, 0.0))[0]
        gw = S.Gateway(
            running=running, pid=g.get("pid"),
            uptime_s=(g.get("uptime_s", 0.0) + (age or 0.0)) if running else g.get("uptime_s"),
            heartbeat_age_s=age, clock_scale=scale, link=link_from_status(z, bool(running)),
            outbox=outbox, disk=self._disk(), ingest=dict(status.get("ingest", ({}, 0.0))[0]),
            ingest_t=status["ingest"][1] if "ingest" in status else None, diagnosis=diag)
        self._refused = {int(k): v for k, v in refused.items()} if isinstance(refused, dict) else {}
        return gw, now, notes

    def _latest_time(self) -> float | None:
        r = self.conn.execute("SELECT max(last_seen) FROM devices").fetchone()
        return r[0] if r else None

    def _disk(self) -> S.Disk:
        size = sum(p.stat().st_size for p in (self.path, Path(f"{self.path}-wal")) if p.exists())
        try:
            du = shutil.disk_usage(self.path.parent)
        except OSError:
            return S.Disk(size, path=str(self.path))
        return S.Disk(size, du.free, du.total, str(self.path))

    # -- greenhouses ------------------------------------------------------------------------
    def _greenhouses(self, now: float | None) -> list[S.GreenhouseView]:
        c = self.conn
        out = []
        rows = c.execute("SELECT name, farm, inside_device, outside_device, model, config "
                         "FROM greenhouses ORDER BY name").fetchall()
        states = {}
        r = c.execute("SELECT value FROM gateway_status WHERE name='greenhouses'").fetchone()
        if r:
            states = json.loads(r[0])
        for name, farm, inside, outside, model, config in rows:
            cfg = json.loads(config)
            end = now if now is not None else time.time()
            first = c.execute("SELECT min(minute) FROM minute WHERE device_id=? AND minute>?",
                              (inside, end - S.DAY)).fetchone()[0]
            span = S.span_of(first, end)
            series = {}
            for side, dev in (("inside", inside), ("outside", outside)):
                series.update(self._minute_series(dev, SIDES[side], end, span))
            out.append(S.GreenhouseView(
                name=name, farm=farm, model=model, inside_device=inside, outside_device=outside,
                state=str(states.get(name, {}).get("state", "")),
                inside=self._reading(inside, SIDES["inside"]),
                outside=self._reading(outside, SIDES["outside"]),
                series=series, temperature=self._temperature(name, end, span),
                parameters=self._parameters(name, model, cfg),
                ventilation=self._ventilation(name, cfg),
                findings=tuple(_finding(f) for f in sorted(findings(c, name), key=lambda f: f.last_seen))))
        return out

    def _reading(self, device: int, channels: tuple[str, ...]) -> S.Reading:
        cols = ", ".join(f"{ch}, {ch}_st" for ch in channels)
        r = self.conn.execute(f"SELECT t, {cols} FROM samples WHERE device_id=? "
                              "ORDER BY boot DESC, seq DESC LIMIT 1", (device,)).fetchone()
        if r is None:
            return S.Reading(device_id=device)
        vals = {ch: r[1 + 2 * i] for i, ch in enumerate(channels)}
        st = {ch: STATUS_NAMES.get(r[2 + 2 * i], str(r[2 + 2 * i])) for i, ch in enumerate(channels)}
        return S.Reading(r[0], device, vals, st)

    def _minute_series(self, device: int, channels: tuple[str, ...], end: float,
                       span: float) -> dict[str, S.Series]:
        cols = ", ".join(f"{ch}, {ch}_qc" for ch in channels)
        rows = self.conn.execute(f"SELECT minute, {cols} FROM minute WHERE device_id=? AND minute>? "
                                 "AND minute<=?", (device, end - S.DAY, end)).fetchall()
        out = {}
        for i, ch in enumerate(channels):
            pts = [(r[0] + 30.0, r[1 + 2 * i]) for r in rows if not r[2 + 2 * i] & DROP]
            out[ch] = S.bin_series(pts, end, self.bins, span)
        return out

    def _temperature(self, gh: str, end: float, span: float) -> S.Temperature:
        c = self.conn
        t = c.execute("SELECT max(t) FROM estimates_latest WHERE greenhouse=? AND "
                      "name='t_in_next'", (gh,)).fetchone()[0]
        if t is None:
            return S.Temperature()
        at = {(src, name): (v, info) for src, name, v, info in c.execute(
            "SELECT source, name, value, info FROM estimates WHERE greenhouse=? AND t=?", (gh, t))}
        pred = c.execute("SELECT value FROM estimates WHERE greenhouse=? AND name='t_in_next' "
                         "AND t=?", (gh, t - 60)).fetchone()
        fc = {int(n[5:-3]): v for (src, n), (v, _) in at.items() if src == "forecast" and v is not None}
        outlook = next((info for (src, _), (_, info) in at.items() if src == "forecast"), "")
        skill = tuple(forecast_skill(c, gh, h, end - SKILL_SPAN) for h in sorted(fc))
        measured = [(tt + 30.0, v) for tt, v in c.execute(
            "SELECT t, value FROM estimates WHERE greenhouse=? AND name='t_in' AND t>?",
            (gh, end - S.DAY))]
        h_max = max(fc, default=60)
        fseries = [(tt + 60 * h_max + 30.0, v) for tt, v in c.execute(
            "SELECT t, value FROM estimates WHERE greenhouse=? AND name=? AND t>?",
            (gh, f"t_in+{h_max}min", end - S.DAY - 60 * h_max))]
        return S.Temperature(
            t=t, measured=at.get(("measured", "t_in"), (None, ""))[0],
            predicted=pred[0] if pred else None, forecasts=fc, outlook=outlook, skill=skill,
            measured_series=S.bin_series(measured, end, self.bins, span),
            forecast_series=S.bin_series(fseries, end, self.bins, span))

    def _parameters(self, gh: str, model: str, cfg: dict[str, Any]) -> tuple[S.Parameter, ...]:
        names, lo, hi = self._model_bounds(gh, model, cfg)
        out = []
        for i, name in enumerate(names):
            r = self.conn.execute("SELECT value, unit FROM estimates_latest WHERE greenhouse=? "
                                  "AND name=? AND source='online'", (gh, name)).fetchone()
            if r is not None and r[0] is not None:
                out.append(S.Parameter(name, r[0], r[1], lo[i], hi[i]))
        return tuple(out)

    def _model_bounds(self, gh: str, model: str, cfg: dict[str, Any]
                      ) -> tuple[list[str], list[float | None], list[float | None]]:
        """The model's parameter names and hard bounds (from the greenhouse file the config
        names; without it, the names stored and no bounds)."""
        if gh not in self._bounds:
            try:
                from gateway.greenhouse import load_greenhouse
                from gateway.model import build_model

                g = load_greenhouse(cfg["greenhouse"])
                m = build_model(model, g)
                lo, hi = m.bounds(g)
                self._bounds[gh] = (list(m.names), lo.tolist(), hi.tolist())
            except Exception:  # a file gone or changed: show the values without bounds
                t = self.conn.execute("SELECT max(t) FROM estimates_latest WHERE greenhouse=? "
                                      "AND name='t_in_next'", (gh,)).fetchone()[0]
                names = [r[0] for r in self.conn.execute(
                    "SELECT name FROM estimates WHERE greenhouse=? AND t=? AND source='online' "
                    "AND name<>'t_in_next' ORDER BY id", (gh, t))]
                return names, [None] * len(names), [None] * len(names)
        return self._bounds[gh]

    def _why_no_sensor(self, gh: str, cfg: dict[str, Any]) -> str:
        """Why no shipped sensor fits the greenhouse file the config names ("" when one does or
        the file cannot be read: the screen then says only that none is set)."""
        if gh not in self._no_sensor:
            try:
                from gateway.greenhouse import load_greenhouse
                from gateway.vsensor.fit import no_sensor_reason

                self._no_sensor[gh] = no_sensor_reason(load_greenhouse(cfg["greenhouse"]))
            except Exception:  # a file gone or changed, a model unreadable: no reason given
                self._no_sensor[gh] = ""
        return self._no_sensor[gh]

    def _ventilation(self, gh: str, cfg: dict[str, Any]) -> S.Ventilation:
        configured = bool(cfg.get("vsensor"))
        got = {}
        for name in ("ventilation_flow", "ventilation_heat_loss"):
            got[name] = self.conn.execute(
                "SELECT t, value, info FROM estimates_latest WHERE greenhouse=? AND name=? "
                "ORDER BY t DESC LIMIT 1", (gh, name)).fetchone()
        flow, loss = got["ventilation_flow"], got["ventilation_heat_loss"]
        if flow is None:
            return S.Ventilation(configured, why_none="" if configured else self._why_no_sensor(gh, cfg))
        return S.Ventilation(configured, flow[0], flow[1], loss[1] if loss else None,
                             flow[2] == "out_of_range")

    # -- kits ---------------------------------------------------------------------------------
    def _kits(self, now: float | None, ghs: list[S.GreenhouseView],
              status: dict[str, tuple[Any, float]]) -> list[S.Kit]:
        roles: dict[int | None, list[str]] = {}  # None: a greenhouse without that kit
        for g in ghs:
            if g.inside_device == g.outside_device:
                roles.setdefault(g.inside_device, []).append(f"{g.name} in+out")
            else:
                roles.setdefault(g.inside_device, []).append(f"{g.name} in")
                roles.setdefault(g.outside_device, []).append(f"{g.name} out")
        health = {h.device_id: h for h in device_health(self.conn)}
        out = []
        for dev in sorted(set(health) | {d for d in roles if d is not None}):
            h = health.get(dev)
            ref = self._refused.get(dev)
            refused = (f"{ref.get('reason')} x{ref.get('count')}; recover: {ref.get('recovery')}"
                       if isinstance(ref, dict) else "")
            last = h.last_sample_t if h else None
            out.append(S.Kit(dev, tuple(roles.get(dev, [])), last, h.records if h else 0,
                             h.board_boot if h else None, h.boot if h else None,
                             dict(h.channels) if h else {}, S.silent(last, now), refused,
                             h.lost if h else 0, _board(h.board) if h and h.board else None))
        return out


def _board(r: BoardReport) -> S.BoardCounters:
    return S.BoardCounters(r.dropped_full, r.dropped_old, r.send_errors, r.heap_free, r.uptime_s,
                           r.rssi_dbm, r.t_recv)


def forecast_skill(conn: sqlite3.Connection, greenhouse: str, horizon_min: int,
                   since: float = -math.inf) -> S.Skill:
    """The ``horizon_min`` forecasts issued since ``since`` whose validity minute has a measured
    T_in, against it, beside persistence (the T_in measured at issue) on the same minutes."""
    rows = conn.execute(
        "SELECT f.value, m0.value, m1.value FROM estimates f "
        "JOIN estimates m0 ON m0.greenhouse=f.greenhouse AND m0.name='t_in' AND m0.t=f.t "
        "JOIN estimates m1 ON m1.greenhouse=f.greenhouse AND m1.name='t_in' AND m1.t=f.t+? "
        "WHERE f.greenhouse=? AND f.name=? AND f.t>=? AND f.value IS NOT NULL "
        "AND m0.value IS NOT NULL AND m1.value IS NOT NULL",
        (60.0 * horizon_min, greenhouse, f"t_in+{horizon_min}min",
         since if math.isfinite(since) else -1e300)).fetchall()
    return S.skill_from_pairs(horizon_min, rows)


def link_from_status(z: dict[str, Any], running: bool) -> S.Link:
    """The ``gateway_status.zenoh`` row → :class:`Link` (up: a peer or router is connected)."""
    if not z:
        return S.Link(enabled=True, up=None, summary="unknown (no status from the gateway)")
    if not z.get("enabled", True):
        return S.Link(enabled=False, up=None, summary="off ([zenoh] enabled = false)")
    peers, routers = int(z.get("peers", 0)), int(z.get("routers", 0))
    waiting = tuple(z.get("waiting_keys", ()))
    up = (peers + routers > 0) if running else None
    if not running:
        words = "unknown (the gateway is not running)"
    elif up:
        words = (f"up: {peers} peer{'s' * (peers != 1)}, {routers} router{'s' * (routers != 1)}, "
                 f"{z.get('matched_keys', 0)} keys listened to")
    else:
        words = "DOWN: no peer or router connected"
    if waiting and running:
        words += f"; {len(waiting)} key{'s' * (len(waiting) != 1)} held (nobody listens)"
    return S.Link(True, up, words, tuple(z.get("endpoints", ())), waiting, z.get("published"))


def _finding(f) -> S.Finding:
    d = f.detail if isinstance(f.detail, dict) else {}
    return S.Finding(f.id, f.effect, str(d.get("summary") or f.effect), f.start, f.first_seen,
                     f.last_seen, f.revision)


def _store_notes(store: Any, running: bool | None, disk: S.Disk, wall: float) -> list[str]:
    """A store the gateway could not write (gateway/store/outage.py): as its status row says
    (written once writes succeed again: a failure in progress shows as a stale heartbeat, said
    with the disk's free space when that is the cause) and its latest failure for a day."""
    out = []
    if running is False and disk.free_bytes is not None and disk.free_bytes < LOW_FREE_BYTES:
        out.append(f"the store's disk is full ({disk.free_bytes} bytes free): a running gateway "
                   "cannot write its heartbeat and holds the kits' records unacknowledged")
    if not isinstance(store, dict):
        return out
    if store.get("failing"):
        out.append(f"store unwritable since {_wall(store.get('since'), wall)}: "
                   f"{store.get('cause')}")
    last = store.get("last")
    if isinstance(last, dict) and wall - float(last.get("until") or 0.0) < 86400:
        out.append(f"store unwritable {_wall(last.get('since'), wall)}–"
                   f"{_wall(last.get('until'), wall)}: {last.get('cause')}; nothing acknowledged "
                   "was lost (the kits held their records)")
    return out


def _wall(t: Any, wall: float) -> str:
    """A wall time [unix s] as HH:MM, with the date unless it is today's."""
    if not t:
        return "?"
    same_day = time.localtime(float(t))[:3] == time.localtime(wall)[:3]
    return time.strftime("%H:%M" if same_day else "%Y-%m-%d %H:%M", time.localtime(float(t)))


def _ago(s: float | None) -> str:
    if s is None:
        return "?"
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"


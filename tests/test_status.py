"""The status screen's data layer (snapshots from the store and from the gateway's messages), its
panels, and ``gateway status --once`` into a pipe; the Textual app is in test_status_app.py.

The store is filled in process the way the service fills it (tests/status_store.py): the
simulator's kit records, the real estimator, the real message producers and status rows."""

from __future__ import annotations

import json
import math
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gateway.protocol import CHANNELS
from gateway.publish import payloads as P
from gateway.status import render
from gateway.status import snapshot as S
from gateway.status.formats import sparkline
from gateway.status.messages import Messages
from gateway.status.snapshot import Link, attention
from gateway.status.store_source import DROP
from gateway.store import Store
from gateway.store.aggregate import aggregate
from gateway.store.live import set_status
from tests.status_helpers import beating, fresh_status, snap_of
from tests.status_store import MODEL, Filled, records

ROOT = Path(__file__).resolve().parents[1]


# -- the data layer ------------------------------------------------------------------------------
def test_store_snapshot_holds_what_the_store_holds(store: Filled) -> None:
    beat = fresh_status(store)
    snap = snap_of(store, wall=beat + 0.1)
    assert snap.now == pytest.approx(store.now + 30, abs=0.1)  # the 300× clock, 0.1 s later
    (g,) = snap.greenhouses
    assert (g.name, g.model, g.inside_device, g.state) == ("north", "prototype", 7, "running")
    with sqlite3.connect(store.path) as c:
        last = c.execute("SELECT t, t_in, rh_out FROM samples WHERE device_id=7 "
                         "ORDER BY seq DESC LIMIT 1").fetchone()
        est = {n: v for n, v in c.execute(
            "SELECT name, value FROM estimates WHERE t=(SELECT max(t) FROM estimates WHERE "
            "name='t_in_next')")}
        rows = c.execute("SELECT t, name, value FROM estimates WHERE source IN ('measured', "
                         "'forecast')").fetchall()
    assert (g.inside.t, g.inside.values["t_in"], g.outside.values["rh_out"]) == last
    assert g.series["t_in"].finite and len(g.series["t_in"].values) == S.FINE_BINS
    t = g.temperature
    assert t.measured == est["t_in"] and t.forecasts[60] == est["t_in+60min"]
    assert sorted(t.forecasts) == [15, 30, 60] and t.outlook == "hold-latest"
    # the forecast error, recomputed here from the raw rows
    measured = {tt: v for tt, n, v in rows if n == "t_in"}
    for s in t.skill:
        pairs = [(v, measured[tt], measured[tt + 60 * s.horizon_min]) for tt, n, v in rows
                 if n == f"t_in+{s.horizon_min}min" and tt in measured
                 and tt + 60 * s.horizon_min in measured]
        a = np.array(pairs)
        assert s.n == len(pairs) > 0
        assert s.mae == pytest.approx(np.mean(np.abs(a[:, 0] - a[:, 2])))
        assert s.persistence_mae == pytest.approx(np.mean(np.abs(a[:, 1] - a[:, 2])))
    assert [p.name for p in g.parameters] == list(MODEL.names)
    assert all(p.lower is not None and p.lower <= p.value <= p.upper for p in g.parameters)
    assert not g.ventilation.configured and g.ventilation.flow is None
    (f,) = g.findings
    assert (f.effect, f.revision) == ("heat_source", 1) and "heater" in f.summary
    kits = {k.device_id: k for k in snap.kits}
    assert (kits[7].greenhouses, kits[7].silent, kits[7].records) == (("north in+out",), False, 130)
    assert kits[9].greenhouses == () and kits[9].silent and kits[9].channels["rain"] == "timeout"
    gw = snap.gateway
    assert gw.running and gw.link.up and gw.outbox.pending == 0 and gw.rejects == {"bad_tag": 3}
    assert gw.disk.store_bytes and gw.disk.free_bytes
    assert attention(snap) == []


def test_a_rotated_key_shows_the_boards_own_boot_counter(store: Filled) -> None:
    s = Store(store.path)
    try:  # kit 7 reflashed: its new key's base is above every boot stored, the board counts 0, 1
        s.set_meta("boot_base/7/aaaaaaaaaaaa", "0")
        s.set_meta("boot_base/7/bbbbbbbbbbbb", "1")
        s.write_batch(records(7, range(130, 132), boot=2))  # the board's boot 1 under base 1
    finally:
        s.close()
    kit = next(k for k in snap_of(store).kits if k.device_id == 7)
    assert (kit.boot, kit.stored_boot) == (1, 2)
    assert "stored as boot 2" in "\n".join(t.plain for t in render.kit_lines(snap_of(store)))


def _ranges(snap) -> dict[str, tuple[float, float, float]]:
    """The greenhouse panel's channel lines, as printed: label → (latest, min, max)."""
    out = {}
    for label in ("T in", "RH in", "T out", "RH out", "I glob", "wind"):
        line = next(t.plain for t in render.greenhouse_lines(snap, 0) if t.plain.startswith(label))
        words = line[len(label):].split()
        lo, hi = words[-1].split("..")
        out[label] = (float(words[0]), float(lo), float(hi))
    return out


def test_the_range_beside_a_sparkline_holds_the_latest_reading(store: Filled) -> None:
    """The screen once showed a latest wind of 5.6 m/s beside 1.9..5.4: the range was of the
    sparkline's bins, means of several minutes. It is of the minutes themselves and of the latest
    reading, also while that reading's minute is not aggregated yet."""
    wind = CHANNELS.index("wind")
    with sqlite3.connect(store.path) as c:
        top = c.execute("SELECT max(wind) FROM minute WHERE device_id=7").fetchone()[0]
    rec, at = records(7, range(130, 131))[0]
    gust = round(top + 1.3, 1)  # as the panel prints it ({:.1f})
    rec = rec._replace(values=rec.values[:wind] + (gust,) + rec.values[wind + 1:])
    s = Store(store.path)
    try:
        s.write_batch([(rec, at)])  # stored, its minute not aggregated yet
    finally:
        s.close()
    beat = fresh_status(store)
    before = _ranges(snap_of(store, wall=beat + 0.1))
    assert before["wind"] == (gust, before["wind"][1], gust)
    for label, (latest, lo, hi) in before.items():
        assert lo <= latest <= hi, label
    s = Store(store.path)
    try:
        while aggregate(s.conn):
            pass
    finally:
        s.close()
    snap = snap_of(store, wall=beat + 0.1)
    g = snap.greenhouses[0]
    with sqlite3.connect(store.path) as c:  # the minutes the panel bins (each at its middle)
        rows = c.execute("SELECT wind FROM minute WHERE device_id=7 AND minute>? AND minute<=? "
                         "AND wind_qc & ? = 0", (g.series["wind"].start - 30, snap.now - 30,
                                                 DROP)).fetchall()
    assert g.series["wind"].extent == (min(r[0] for r in rows), max(r[0] for r in rows))
    assert g.series["wind"].extent[1] == pytest.approx(gust)
    assert g.series["wind"].rebinned(36).hi < gust - 0.05  # the drawn bins' means stay below it
    after = _ranges(snap)
    assert after["wind"][2] == gust
    for label, (latest, lo, hi) in after.items():
        assert lo <= latest <= hi, label


def test_the_measured_range_is_of_the_measurements_alone(store: Filled) -> None:
    """Under "Inside T" the range beside "measured" was of the bins of both sparklines, the
    measured and the +60-min forecasts (12.3..17.9 beside a T in row of 12.8..16.4). It is of the
    measured minutes and the latest measured alone; the two sparklines keep their common scale,
    for drawing only. Here two forecasts valid inside the window are far off, one each way."""
    wall = fresh_status(store) + 0.1  # one instant for every snapshot (a 300x clock)
    snap = snap_of(store, wall=wall)
    g = snap.greenhouses[0]
    ms = g.temperature.measured_series
    assert ms is not None and snap.now is not None
    with sqlite3.connect(store.path) as c:  # the minutes the panel bins (each at its middle)
        rows = [r[0] for r in c.execute(
            "SELECT value FROM estimates WHERE greenhouse='north' AND name='t_in' AND t+30>? "
            "AND t+30<=? AND value IS NOT NULL", (ms.start, snap.now))]
        lo, hi = min(rows + [g.temperature.measured]), max(rows + [g.temperature.measured])
        valid = "FROM estimates WHERE greenhouse='north' AND name='t_in+60min' AND t+3630<=?"
        first = c.execute(f"SELECT min(t) {valid}", (snap.now,)).fetchone()[0]
        last = c.execute(f"SELECT max(t) {valid}", (snap.now,)).fetchone()[0]
        assert first is not None and last - first > 1800  # not in the same bin
        c.execute("UPDATE estimates SET value=? WHERE greenhouse='north' AND name='t_in+60min' "
                  "AND t=?", (hi + 10.0, first))
        c.execute("UPDATE estimates SET value=? WHERE greenhouse='north' AND name='t_in+60min' "
                  "AND t=?", (lo - 10.0, last))
    snap = snap_of(store, wall=wall)
    t = snap.greenhouses[0].temperature
    assert t.forecast_series is not None and t.measured_series is not None
    assert t.forecast_series.hi > hi + 0.5 and t.forecast_series.lo < lo - 0.5
    lines = [x.plain for x in render.greenhouse_lines(snap, 0)]
    line = next(x for x in lines if x.startswith("measured "))
    assert line.endswith(f" {lo:.1f}..{hi:.1f} °C"), line
    # the sparklines share one scale, the bins' of both as drawn (36 at 78 columns), for drawing
    measured, forecast = t.measured_series.rebinned(36), t.forecast_series.rebinned(36)
    scale = (min(measured.lo, forecast.lo), max(measured.hi, forecast.hi))
    assert sparkline(measured, *scale) in line
    ahead = next(x for x in lines if x.startswith("+60 min "))
    assert sparkline(forecast, *scale) in ahead


def test_the_ventilation_estimate_when_a_virtual_sensor_is_set(store: Filled) -> None:
    # none set on biskra-prototype (0.68 m2, no vents): the shipped sensors' house is another
    # (their ONNX metadata's signature), which the line says, in 80 columns
    lines = [t.plain for t in render.greenhouse_lines(snap_of(store), 0)]
    line = next(x for x in lines if x.startswith("Ventilation"))
    assert line == "Ventilation no virtual sensor: shipped ones fit almeria-palmerillas only"
    assert len(line) <= 80
    with sqlite3.connect(store.path) as c:  # the house they were trained on: no reason to give
        cfg = json.loads(c.execute("SELECT config FROM greenhouses").fetchone()[0])
        c.execute("UPDATE greenhouses SET config=?",
                  (json.dumps(dict(cfg, greenhouse="almeria-palmerillas")),))
    lines = [t.plain for t in render.greenhouse_lines(snap_of(store), 0)]
    assert "Ventilation no virtual sensor" in lines
    with sqlite3.connect(store.path) as c:  # the config names a sensor; its rows as the pipeline writes them
        c.execute("UPDATE greenhouses SET config=?", (json.dumps(dict(cfg, vsensor="v.onnx")),))
    text = "\n".join(t.plain for t in render.greenhouse_lines(snap_of(store), 0))
    assert "Ventilation virtual sensor set, no estimate yet" in text
    with sqlite3.connect(store.path) as c:
        c.executemany("INSERT INTO estimates (greenhouse, t, source, name, value, unit, info) "
                      "VALUES ('north', ?, 'vsensor', ?, ?, ?, ?)",
                      [(store.now - 91, "ventilation_flow", 0.5, "m3 s-1", ""),
                       (store.now - 91, "ventilation_heat_loss", 30.0, "W m-2", ""),
                       (store.now - 31, "ventilation_flow", 0.412, "m3 s-1", "out_of_range"),
                       (store.now - 31, "ventilation_heat_loss", 41.6, "W m-2", "out_of_range")])
    v = snap_of(store).greenhouses[0].ventilation
    assert (v.configured, v.flow, v.heat_loss, v.out_of_range) == (True, 0.412, 41.6, True)
    text = "\n".join(t.plain for t in render.greenhouse_lines(snap_of(store), 0))
    assert "Ventilation 0.412 m³/s · heat loss 42 W/m² at 08:10Z · inputs out of its range" in text


def test_gateway_down_link_down_and_outbox_alarm_are_said(store: Filled) -> None:
    beat = fresh_status(store, peers=0, waiting=("serra/f1/north/forecast",), alarm_at=500)
    with sqlite3.connect(store.path) as c:  # nobody listened: every message still waits
        c.execute("UPDATE outbox SET sent = NULL")
        n = c.execute("SELECT count(*) FROM outbox").fetchone()[0]
    snap = snap_of(store, wall=beat + 0.1)
    assert snap.gateway.link.up is False and snap.gateway.outbox.pending == n > 500
    text = "\n".join(t.plain for t in render.gateway_lines(snap))
    assert "Zenoh      DOWN: no peer or router connected\n           1 key held (nobody" in text
    assert f"Outbox     ALARM: {n} waiting since 2009-11-01 06:00Z · alarm at 500 of 1000" in text
    assert set(attention(snap)) == {"the Zenoh link is down", f"outbox alarm: {n} messages waiting"}
    stale = snap_of(store, wall=beat + 600)  # no heartbeat for 10 minutes
    assert stale.gateway.running is False and stale.gateway.link.up is None
    assert "NOT RUNNING · last heartbeat 10 min ago" in "\n".join(
        t.plain for t in render.gateway_lines(stale))
    assert stale.now == pytest.approx(store.now)  # a stopped test clock stands still
    assert "the gateway is not running" in attention(stale)
    # a clean stop writes its last status with `stopped`: not running at once, its clock standing
    beat = fresh_status(store, stopped=time.time())
    stopped = snap_of(store, wall=beat + 0.1)
    assert stopped.gateway.running is False and stopped.now == pytest.approx(store.now)
    assert "NOT RUNNING · last heartbeat 0 s ago" in "\n".join(
        t.plain for t in render.gateway_lines(stopped))


def test_a_scaled_clock_says_which_times_are_wall_and_when_the_counters_were_taken(
        store: Filled) -> None:
    """At 300× the gateway's uptime and heartbeat (its process's, wall) are said to be wall and
    its uptime is given on the scaled clock too; the packet counters, written every 5 wall s,
    are said as of when, so "stored" trailing the records column does not read as data lost."""
    beat = fresh_status(store)  # scale 300, up 3600 wall s, every row at the trace's now
    s = Store(store.path)
    try:  # the counters as the gateway wrote them 10 minutes (its clock) before that
        set_status(s.conn, {"ingest": {"stored": 120, "duplicate": 0}}, store.now - 600)
    finally:
        s.close()
    snap = snap_of(store, wall=beat)
    gw = [t.plain for t in render.gateway_lines(snap)]
    assert gw[0] == "Service    running · pid 4242 · up 60 min · heartbeat 0 s ago (wall clock)"
    assert gw[2] == "           up 12.5 days on it; every other time on the screen is on it"
    kits = [t.plain for t in render.kit_lines(snap)]
    i = next(i for i, x in enumerate(kits) if x.startswith("Packets    120 stored"))
    when = time.strftime("%H:%MZ", time.gmtime(store.now - 600))
    assert kits[i + 1] == f"           since the gateway started, as of its status at {when} (10 min ago)"
    assert next(k for k in snap.kits if k.device_id == 7).records == 130  # the store, now
    stopped = snap_of(store, wall=beat + 600)  # no heartbeat for 10 wall minutes
    assert [t.plain for t in render.gateway_lines(stopped)][2] == \
        "           every time on the screen but the heartbeat's is on it"
    fresh_status(store, scale=1.0, heartbeat=beat)  # a real clock: one clock, nothing to say
    gw = [t.plain for t in render.gateway_lines(snap_of(store, wall=beat))]
    assert gw[0].endswith("heartbeat 0 s ago") and gw[1].startswith("Clock") and "on it" not in gw[2]


def test_empty_store_and_ingest_only_store(tmp_path: Path) -> None:
    Store(tmp_path / "empty.db").close()
    snap = snap_of(Filled(tmp_path / "empty.db", 0, 0))
    assert snap.greenhouses == () and snap.kits == () and snap.gateway.running is None
    assert any("no gateway service has run" in n for n in snap.notes)
    text = render.plain(snap)
    for want in ("No greenhouse in this store yet.", "no kit has sent a record yet",
                 "unknown: no status from a gateway"):
        assert want in text
    assert attention(snap) == []


def diagnosis_run(now: float, *notes: tuple[str, str]) -> dict:
    """A greenhouse's ``diagnosis`` status row as the service writes it, with notes
    (code, level) whose messages are as long as diagnose's."""
    said = {"site_time_mismatch": "96 % of the radiation above 50 W m-2 is measured while the "
            "sun is below the horizon at latitude 34.85, longitude 5.73 (east positive)",
            "short_heldout": "only 0.8 days are held out"}
    return {"when": now - 3600, "ok": True, "findings": 0,
            "note": "diagnosis of 1.8 days in 12 s: 0 finding(s)",
            "notes": [{"code": c, "level": lv, "message": said.get(c, f"{c} went wrong")}
                      for c, lv in notes]}


def test_the_diagnosis_warnings_are_shown_under_its_run(store: Filled) -> None:
    """The run's notes were kept in its status row but not shown. A warning (the figures are
    likely wrong) now gets a line of its own under the run on the gateway panel and is named on
    the greenhouse's findings line; a plain note adds nothing (it is in the row and the log)."""
    run = diagnosis_run(store.now, ("site_time_mismatch", "warning"), ("short_heldout", "note"))
    beat = fresh_status(store, diagnosis={"north": run})
    snap = snap_of(store, wall=beat + 0.1)
    gw = [t.plain for t in render.gateway_lines(snap)]
    i = next(k for k, line in enumerate(gw) if line.startswith("Diagnosis  north: last run "))
    assert gw[i + 1].startswith("           warning site_time_mismatch: 96 % of the radiation ")
    assert gw[i + 1].endswith(" …") and len(gw[i + 1]) <= render.WIDTH  # cut, never wrapped
    assert not gw[i + 2].startswith("     ")  # one warning, one line; no line for the note
    text = render.plain(snap)
    assert "Findings   1 · diagnosis warning: site_time_mismatch (last run " in text
    assert gw[i + 1] in text  # --once has it too
    assert attention(snap) == ["diagnosis of north warns: site_time_mismatch"]  # --once exits 1
    quiet = diagnosis_run(store.now, ("short_heldout", "note"))
    snap = snap_of(store, wall=fresh_status(store, diagnosis={"north": quiet}) + 0.1)
    gw = [t.plain for t in render.gateway_lines(snap)]
    i = next(k for k, line in enumerate(gw) if line.startswith("Diagnosis  north: last run "))
    text = render.plain(snap)
    assert not gw[i + 1].startswith("     ") and "warning " not in text and "short_" not in text
    assert attention(snap) == []  # a note needs nobody
    failed = {**quiet, "ok": False, "note": "diagnosis abandoned after 600 s"}
    snap = snap_of(store, wall=fresh_status(store, diagnosis={"north": failed}) + 0.1)
    assert attention(snap) == ["diagnosis of north failed"]
    many = diagnosis_run(store.now, *[(f"code_{k}", "warning") for k in range(5)])
    snap = snap_of(store, wall=fresh_status(store, diagnosis={"north": many}) + 0.1)
    gw = [t.plain for t in render.gateway_lines(snap)]
    i = next(k for k, line in enumerate(gw) if line.startswith("Diagnosis  north: last run "))
    assert gw[i + 1:i + 5] == ["           warning code_0: code_0 went wrong",
                               "           warning code_1: code_1 went wrong",
                               "           warning code_2: code_2 went wrong",
                               "           and 2 more warnings (the gateway's log)"]
    findings_line = next(t.plain for t in render.greenhouse_lines(snap, 0)
                         if t.plain.startswith("Findings"))
    assert findings_line.startswith("Findings   1 · diagnosis warnings: code_0, code_1, code_2, ")
    assert all(len(t.plain) <= render.WIDTH for panel in render.PANELS
               for t in render.panel_lines(snap, panel))


def test_a_diagnosis_row_left_incomplete_is_read_as_far_as_it_goes(store: Filled) -> None:
    """A ``diagnosis`` status row without ``ok`` read as a failed run (``--once`` exited 1 for
    it), one whose time was NaN or out of range stopped the snapshot (``time.gmtime`` raises),
    and notes that were not a list raised too. Now the time is "?", an unknown outcome is said
    as such and calls nobody, a false ``ok`` is still a failure, odd notes are none."""
    rows = {"north": {"when": math.nan, "findings": 0, "note": "diagnosis of 1.8 days",
                      "notes": {"code": "site_time_mismatch", "level": "warning"}},
            "south": {"when": 1e30, "ok": False, "notes": 5},
            "west": {"when": None, "ok": True, "notes": [{"code": "c", "level": "warning"}, "x"]}}
    snap = snap_of(store, wall=fresh_status(store, diagnosis=rows) + 0.1)
    diag = snap.gateway.diagnosis
    assert diag["north"] == S.Diagnosis("last run ? outcome unknown, 0 findings "
                                        "(diagnosis of 1.8 days)", (), True)
    assert diag["south"] == S.Diagnosis("last run ? failed", (), False)
    assert diag["west"] == S.Diagnosis("last run ? ok", (("c", ""),), True)
    assert attention(snap) == ["diagnosis of south failed", "diagnosis of west warns: c"]
    assert "Diagnosis  north: last run ? outcome unknown" in render.plain(snap)


def test_every_panel_line_fits_80_columns(store: Filled) -> None:
    beat = fresh_status(store, peers=0, waiting=("a", "b"), pending=900,
                        ingest={"stored": 10**7, "duplicate": 10**6, "bad_tag": 12345,
                                "replay_old_boot": 999, "too_short": 77, "bad_magic": 5,
                                "unknown_device": 3, "out_of_range": 2, "bad_version": 1},
                        refused={"7": {"reason": "replay_old_boot", "count": 42,
                                       "recovery": "python -m gateway keys rotate 7 --keys "
                                       "/etc/serra/keys.txt"}})
    snap = snap_of(store, wall=beat + 1)
    for panel in render.PANELS:
        for line in render.panel_lines(snap, panel):
            assert len(line.plain) <= render.WIDTH, line.plain
    assert "REFUSED" in render.plain(snap) and "keys rotate 7" in render.plain(snap)


def test_messages_give_the_same_numbers_as_the_store(store: Filled) -> None:
    """The Zenoh source's data layer on the real payloads the producers made (their outbox)."""
    beat = fresh_status(store)
    from_store = snap_of(store, wall=beat)
    m = Messages()
    with sqlite3.connect(store.path) as c:
        for key, payload in c.execute("SELECT key, payload FROM outbox ORDER BY id"):
            assert m.add(key.replace("north/", "north/history/"), payload)
            assert not m.add(key, payload)  # a repeat (same idempotency key) counts once
    snap = m.snapshot("zenoh test", beat, True, Link(True, True, "this screen: connected"))
    (a,), (b,) = snap.greenhouses, from_store.greenhouses
    assert a.inside.values == pytest.approx(b.inside.values)
    assert a.outside.values["rain"] == b.outside.values["rain"]
    assert a.temperature.forecasts == pytest.approx(b.temperature.forecasts, abs=1e-4)  # rounded
    assert [s.n for s in a.temperature.skill] == [s.n for s in b.temperature.skill]
    for x, y in zip(a.temperature.skill, b.temperature.skill, strict=True):
        assert x.mae == pytest.approx(y.mae, abs=1e-3)  # payloads round to 1e-4 °C
    assert [(p.name, p.lower, p.upper) for p in a.parameters] == [
        (p.name, p.lower, p.upper) for p in b.parameters]
    assert [p.value for p in a.parameters] == pytest.approx([p.value for p in b.parameters])
    kit = next(k for k in snap.kits if k.device_id == 7)
    assert kit.greenhouses == ("north in+out",) and kit.records == 130 and kit.boot == 0
    assert [f.effect for f in a.findings] == ["heat_source"]


# -- the command ----------------------------------------------------------------------------------
def gateway_cmd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "gateway", *args], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)


def test_once_into_a_pipe_is_plain_text_with_an_exit_status(store: Filled, tmp_path: Path) -> None:
    # A gateway clock that barely moves: the time the screen reads stays the store's whatever the
    # wall delay (at the fixture's 300x, one second of delay is five minutes: kit 7 silent).
    with beating(store, scale=1e-9):
        r = gateway_cmd("status", "--db", str(store.path), "--once")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "\x1b" not in r.stdout and "ATTENTION" not in r.stdout
    for want in ("farm f1 · greenhouse north (1/1)", "farm f1 · kits", "farm f1 · gateway",
                 "Findings   1", "   9  (unassigned)"):
        assert want in r.stdout
    # no heartbeat for a while: exit 1 and say why first; without --once into a pipe: the same
    fresh_status(store, heartbeat=time.time() - 600)
    r = subprocess.run([sys.executable, "-m", "gateway", "status", "--db", str(store.path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and r.stdout.startswith("ATTENTION: the gateway is not running\n")
    assert "\x1b" not in r.stdout
    # not a store: one line naming the file, exit 2, nothing written
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as c:
        c.execute("CREATE TABLE t (x)")
    before = other.read_bytes()
    r = gateway_cmd("status", "--db", str(other), "--once")
    assert r.returncode == 2 and r.stderr.startswith(f"error: {other}: not a Serra store")
    assert other.read_bytes() == before
    r = gateway_cmd("status", "--config", str(tmp_path / "none.toml"))
    assert r.returncode == 2 and "none.toml: no such config" in r.stderr


def test_status_help_reads_well() -> None:
    r = gateway_cmd("status", "--help")
    assert r.returncode == 0
    text = " ".join(r.stdout.split())
    for want in ("--db serra.db", "--connect ENDPOINT", "--once", "q quit", "never writes",
                 "exit status 1 when something needs attention", "80×24"):
        assert want in text, want
    assert "status" in gateway_cmd("--help").stdout


def test_skill_of_nothing_is_not_a_number() -> None:
    from gateway.status.snapshot import skill_from_pairs

    s = skill_from_pairs(60, [])
    assert s.n == 0 and math.isnan(s.mae) and json.dumps(s.n) == "0"


def test_records_a_kit_lost_on_the_board_show_on_its_line(store: Filled) -> None:
    """Kit 7's boot 1 sends seqs 140–149 only, then it restarts (boot 2): 0–139 can no longer
    arrive and are counted lost (gateway/store/losses.py); boot 0, whole, adds none. The store
    source and the Zenoh source (the device message) both show them on the kit's line."""
    s = Store(store.path)
    try:
        s.write_batch(records(7, range(140, 150), boot=1))
        s.write_batch(records(7, range(150, 151), boot=2))
    finally:
        s.close()
    snap = snap_of(store)
    assert next(k for k in snap.kits if k.device_id == 7).lost == 140
    lines = [t.plain for t in render.kit_lines(snap)]
    assert lines[0].split()[5] == "lost"
    row = next(x for x in lines if x.startswith("   7  north"))
    assert row.split()[-3:-1] == ["140", "2"], row  # lost, boot
    assert "     140 records lost on the board: ring overflow or restart, never stored" in lines
    assert all(len(x) <= render.WIDTH for x in lines)
    m = Messages()
    doc = P.device("f1", 7, store.now, "d7", state="ok", boot=2, records=141, lost=140,
                   last_seen=store.now, channels={}, greenhouses=[])
    assert m.add("serra/f1/north/device/7", json.dumps(doc))
    kit = next(k for k in m.snapshot("z", store.now, True, Link(True, True, "")).kits
               if k.device_id == 7)
    assert kit.lost == 140


def test_the_records_lost_on_the_boards_are_not_rejected_packets(store: Filled) -> None:
    """The ingest counter lost_on_board counts records, not packets: said beside them."""
    beat = fresh_status(store)
    s = Store(store.path)
    try:
        set_status(s.conn, {"ingest": {"stored": 120, "duplicate": 2, "bad_tag": 3,
                                       "lost_on_board": 40}}, store.now)
    finally:
        s.close()
    snap = snap_of(store, wall=beat)
    assert snap.gateway.rejects == {"bad_tag": 3}
    kits = [t.plain for t in render.kit_lines(snap)]
    assert ("Packets    120 stored · 2 duplicates · 3 rejected · 40 lost on the boards"
            in kits), kits

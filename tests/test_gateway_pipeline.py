"""The live gateway's store side, in process on a real SQLite file: the per-greenhouse estimator
(exact resume from its saved state, causal forecasts, gaps), the message producers (valid
payloads, exactly once, pausing when the outbox is full), findings with a stable identity."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.protocol import BoardHealth
from gateway.publish import validate
from gateway.publish.payloads import Place
from gateway.service.findings import store_findings
from gateway.service.pipeline import GreenhousePipeline, StepReport
from gateway.service.producers import GreenhouseInfo, Producers
from gateway.store import Store
from gateway.store.live import findings
from gateway.store.outbox import Outbox
from tests.gateway_harness import EPOCH, sim_trace, store_trace

GH = replace(load_greenhouse("biskra-prototype"), online={"t_in": {"iterations": 10, "bats": 10}})
"""The kit's house with a small estimator budget in its own ``[online.t_in]`` table (the live
default is 50 × 20): what these tests check is exact, budget-free (resume, causality, gaps,
messages, migration), and the pipelines here step at half the time."""
MODEL = build_model("prototype", GH)
TRACE = sim_trace(days=1.0)


def fill(store: Store, minutes: range, device: int = 7, change_after: int | None = None,
         boot: int = 0) -> None:
    """Records of the simulated trace, one per minute, stamped mid-minute."""
    store_trace(store, TRACE, minutes, device, change_after, boot)


def pipeline() -> GreenhousePipeline:
    return GreenhousePipeline("north", GH, MODEL, 7, 7, None, seed=1)


def rows(store: Store, source: str | None = None) -> list[tuple]:
    sql = "SELECT t, source, name, value, info FROM estimates"
    args: tuple = ()
    if source:
        sql, args = sql + " WHERE source=?", (source,)
    return store.conn.execute(sql + " ORDER BY t, source, name", args).fetchall()


def end(k: int) -> float:
    """A gateway time at which minute k - 1 is final (the kit has sent minute k)."""
    return EPOCH + 60 * k + 31


@pytest.fixture(scope="module")
def whole_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Store, StepReport]:
    """The first 100 minutes stepped by one pipeline in one go, and its report: the run that the
    resume test splits and the causality test changes the future of (both only read it)."""
    store = Store(tmp_path_factory.mktemp("whole") / "a.db")
    fill(store, range(100))
    pa = pipeline()
    pa.resume(store.conn)
    return store, pa.step_pending(store.conn, end(99), 0.0, 600.0)


def test_estimator_resumes_exactly_from_its_saved_state(
        whole_run: tuple[Store, StepReport], tmp_path: Path) -> None:
    whole, rep = whole_run
    assert rep.stepped == 99 and rep.restarts == 0
    split = Store(tmp_path / "b.db")
    fill(split, range(51))
    first = pipeline()
    first.resume(split.conn)
    first.step_pending(split.conn, end(50), 0.0, 600.0)
    assert first.cursor == EPOCH + 60 * 49  # minute 50 is not final: the kit may send more
    fill(split, range(51, 100))
    second = pipeline()  # a restarted gateway: a new estimator, resumed from the store
    assert "resumed" in second.resume(split.conn)
    second.step_pending(split.conn, end(99), 0.0, 600.0)
    assert rows(split) == rows(whole)
    # the saved snapshot and its journal (its last batch may be one) give the state at the cursor
    third = pipeline()
    assert "resumed" in third.resume(split.conn) and third.est.counters.samples == 99
    sources = {r[1] for r in rows(whole)}
    assert sources == {"online", "measured", "flux", "forecast"}
    fc = rows(whole, "forecast")
    assert {r[2] for r in fc} == {"t_in+15min", "t_in+30min", "t_in+60min"}
    assert {r[4] for r in fc} == {"hold-latest"}  # each forecast names its outlook


def test_forecasts_are_causal(whole_run: tuple[Store, StepReport], tmp_path: Path) -> None:
    a, b = whole_run[0], Store(tmp_path / "b.db")
    fill(b, range(100), change_after=60)  # the same past as ``whole_run``, another future
    pl = pipeline()
    pl.resume(b.conn)
    pl.step_pending(b.conn, end(99), 0.0, 600.0)
    upto = EPOCH + 60 * 60
    fa = [r for r in rows(a, "forecast") if r[0] <= upto]
    fb = [r for r in rows(b, "forecast") if r[0] <= upto]
    assert len(fa) == 3 * 61 and fa == fb
    later = [r for r in rows(a, "forecast") if r[0] > upto + 60]
    assert later != [r for r in rows(b, "forecast") if r[0] > upto + 60]


def test_the_forecast_kind_and_its_saved_state(tmp_path: Path) -> None:
    """The live forecasts are replay's ``combined`` by default (gateway/service/forecaster.py,
    tested step by step against replay in test_forecaster.py), the forecaster's state is saved
    with the estimator's, another kind gives other values on the same rows, and a state saved
    before the forecaster existed resumes with a fresh one."""
    made = {}
    for kind in ("combined", "adaptive"):
        s = Store(tmp_path / f"{kind}.db")
        fill(s, range(80))
        # the snapshot saved with every batch: the test reads and edits it
        pl = GreenhousePipeline("north", GH, MODEL, 7, 7, None, seed=1, forecast=kind,
                                snapshot_every_min=1)
        pl.resume(s.conn)
        pl.step_pending(s.conn, end(79), 0.0, 600.0)
        made[kind] = (s, rows(s, "forecast"))
    s, combined = made["combined"]
    plain = made["adaptive"][1]
    assert [r[:3] for r in combined] == [r[:3] for r in plain] and len(combined) > 100
    assert [r[3] for r in combined] != [r[3] for r in plain]
    state = json.loads(s.conn.execute("SELECT state FROM estimator_state").fetchone()[0])
    assert state["forecaster"]["kind"] == "combined" and state["forecaster"]["arx"]["updates"] > 50
    del state["forecaster"]  # a gateway updated over an older saved state
    s.conn.execute("UPDATE estimator_state SET state=?", (json.dumps(state),))
    again = pipeline()
    assert "resumed" in again.resume(s.conn)
    assert again.forecaster.kf is not None and again.forecaster.kf.estimate() is None
    fill(s, range(80, 90))
    again.step_pending(s.conn, end(89), 0.0, 600.0)
    assert len(rows(s, "forecast")) == len(combined) + 3 * 10


def test_final_minutes_wait_for_the_kit_then_for_the_clock(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    fill(s, range(10))
    pl = pipeline()
    pl.resume(s.conn)
    # the kit's latest record is minute 9: minutes up to 8 are final, 9 is not (it may get more)
    assert pl.step_pending(s.conn, end(9), 0.0, 600.0).last_minute == EPOCH + 60 * 8
    assert pl.step_pending(s.conn, end(9), 0.0, 600.0).stepped == 0
    # the kit falls silent: minute 9 is stepped once max_wait has passed by the clock
    assert pl.step_pending(s.conn, EPOCH + 60 * 10 + 600, 0.0, 600.0).last_minute == EPOCH + 60 * 9


def test_a_gap_restarts_the_window_not_the_parameters(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    fill(s, range(60))
    pl = pipeline()
    pl.resume(s.conn)
    pl.step_pending(s.conn, end(59), 0.0, 600.0)
    fill(s, range(240, 300), boot=1)  # the kit was off for 3 hours
    rep = pl.step_pending(s.conn, end(299), 0.0, 600.0)
    assert rep.restarts == 1 and "3.0 h gap" in rep.notes[0]
    assert rep.stepped == 1 + 59  # minute 59, then no made-up minutes across the gap
    params = {}
    for t, _, name, value, _ in rows(s, "online"):
        params.setdefault(t, {})[name] = value
    before, after = params[EPOCH + 60 * 59], params[EPOCH + 60 * 240]
    assert [after[n] for n in MODEL.names] == [before[n] for n in MODEL.names]  # kept
    assert params[EPOCH + 60 * 250] != after  # and estimated again once the window refilled


def test_a_missing_outside_humidity_is_said_once_per_outage(tmp_path: Path) -> None:
    """Minutes with an outside temperature but no rh_out: the sky temperature falls back to
    Swinbank's (gateway/model/sky.py). The gateway says so once when it starts, not per minute,
    and once when rh_out has been back for ``HUMIDITY_BACK_MIN`` minutes."""
    from gateway.service.pipeline import HUMIDITY_BACK_MIN

    trace = {c: v.copy() for c, v in TRACE.items()}
    trace["rh_out"][20:60] = np.nan  # the outside kit's RH channel fails for 40 minutes
    assert np.isfinite(trace["t_out"][20:60]).all() and np.isfinite(trace["rh_out"][:20]).all()
    s = Store(tmp_path / "g.db")
    last = 60 + HUMIDITY_BACK_MIN + 5
    store_trace(s, trace, range(last + 1))
    pl = pipeline()
    pl.resume(s.conn)
    rep = pl.step_pending(s.conn, end(last), 0.0, 600.0)
    said = [n for n in rep.notes if "rh_out" in n]
    assert len(said) == 2, rep.notes
    assert "2009-11-01T06:20Z" in said[0] and "Swinbank" in said[0]
    assert "back" in said[1] and "2009-11-01T07:00Z" in said[1]


def infos() -> dict[str, GreenhouseInfo]:
    lo, hi = MODEL.bounds(GH)
    return {"north": GreenhouseInfo(Place("f1", "north", 34.85, 5.73), 7, 7, MODEL, lo.tolist(),
                                    hi.tolist())}


def test_producers_make_every_message_once_and_pause_when_the_outbox_is_full(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    outbox = Outbox(s.conn, max_rows=40, alarm_fraction=0.5)
    prod = Producers(s.conn, "f1", infos(), outbox)
    fill(s, range(30))
    fill(s, range(5), device=9)  # a kit no greenhouse uses: stored and reported
    pl = pipeline()
    pl.resume(s.conn)
    pl.step_pending(s.conn, end(29), 0.0, 600.0)
    made = prod.run(limit=7)
    assert outbox.pending() == made <= 40 and prod.counts.full >= 1 and outbox.alarm
    everything = []
    while True:  # the publisher drains, production resumes where it paused
        batch = outbox.peek(1000)
        everything += batch
        outbox.mark_sent([m.id for m in batch])
        if not batch and prod.run(limit=7) == 0:
            break
    assert prod.counts.unassigned == {9}  # stored, no measurement message: reported below
    kinds = [m.key.rsplit("north/", 1)[1] for m in everything]
    assert kinds.count("measurement/inside") == kinds.count("measurement/outside") == 30
    assert kinds.count("forecast") == kinds.count("fluxes") >= 25
    assert kinds.count("parameters") == 29
    idem = [m.idem for m in everything]
    assert len(set(idem)) == len(idem)
    seqs = [json.loads(m.payload)["kitRecord"]["value"]["seq"] for m in everything
            if m.key.endswith("measurement/inside")]
    assert seqs == list(range(30))  # in order
    for m in everything[::7]:
        assert validate.errors(json.loads(m.payload)) == [], m.key
    # kit 7's latest health packet, as ingest keeps it: its own counters go into device/7
    s.note_health(BoardHealth(7, 0, 2, -58, 1800, 30, 0, 0, 31, 30, 0, 0, 41000, 0), 0,
                  EPOCH + 3500)
    snap = prod.snapshots(EPOCH + 3600, 300.0, {"north": {"estimatorState": "running"}})
    assert snap == 3  # status, device/7, device/9 (unassigned)
    keys = {m.key for m in outbox.peek(10)}
    assert keys == {"serra/f1/north/status", "serra/f1/north/device/7", "serra/f1/unassigned/device/9"}
    for m in outbox.peek(10):
        assert validate.errors(json.loads(m.payload)) == []
    dev7 = next(json.loads(m.payload) for m in outbox.peek(10) if m.key.endswith("device/7"))
    assert dev7["recordsDroppedOnBoard"]["value"] == 0 and dev7["rssi"]["value"] == -58
    assert dev7["boardCounters"]["value"]["bootCounter"] == 0
    assert dev7["boardCounters"]["value"]["uptime"] == 1800
    assert "boardCounters" not in next(json.loads(m.payload) for m in outbox.peek(10)
                                       if m.key.endswith("device/9"))


def test_findings_keep_their_identity_and_are_published_once_per_revision(tmp_path: Path) -> None:
    s = Store(tmp_path / "g.db")
    outbox = Outbox(s.conn)
    prod = Producers(s.conn, "f1", infos(), outbox)
    f = {"effect": "solar_gain_change", "start": "2009-11-04T10:00:00Z",
         "params": {"factor": 0.5, "unit": "-"}, "summary": "cover whitened", "evidence": "x"}
    assert "new finding" in store_findings(s.conn, "north", [f], EPOCH)[0]
    assert prod.findings(10) == 1
    # the next daily run finds it again, start estimated 2 h later, amplitude 3 % off: same finding
    again = dict(f, start="2009-11-04T10:40:00Z", params={"factor": 0.515, "unit": "-"})
    assert store_findings(s.conn, "north", [again], EPOCH + 86400) == []
    assert prod.findings(10) == 0  # not re-announced
    moved = dict(f, params={"factor": 0.3, "unit": "-"})
    assert "revision 2" in store_findings(s.conn, "north", [moved], EPOCH + 2 * 86400)[0]
    assert prod.findings(10) == 1
    (row,) = findings(s.conn, "north")
    assert (row.id, row.revision, row.published_revision) == (
        "north:solar_gain_change-20091104T1000Z", 2, 2)
    msgs = outbox.peek(10)
    assert [m.idem for m in msgs] == [f"f1/north/finding/{row.id}/r1", f"f1/north/finding/{row.id}/r2"]
    for m in msgs:
        assert validate.errors(json.loads(m.payload)) == []
    other = dict(f, effect="heat_source", start=None, params={"power": 20.0, "unit": "W m-2"})
    store_findings(s.conn, "north", [other], EPOCH + 3 * 86400)
    assert len(findings(s.conn, "north")) == 2


def test_each_kept_diagnosis_run_is_published_once(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The run the scheduler keeps (``save_run``) becomes one ``diagnosis`` message, made in the
    transaction that moves its cursor: not again on the next pass nor by a new producer on the
    same store (a restart), again for the next run, held while the outbox is full; a kept run
    that cannot be read is passed over with one warning; nothing with the diagnosis off."""
    import logging

    from gateway.service.diagnosis import DiagnosisRun, save_run

    s = Store(tmp_path / "g.db")
    outbox = Outbox(s.conn, max_rows=1)
    prod = Producers(s.conn, "f1", infos(), outbox)
    assert prod.diagnosis_runs(10) == 0  # never run: nothing to say
    notes = [{"code": "site_time_mismatch", "level": "warning", "message": "daylight at night"}]
    first = DiagnosisRun("north", EPOCH, True, "diagnosis of 2.0 days in 9 s: 0 finding(s)", 0,
                         notes)
    save_run(s.conn, first)
    assert prod.diagnosis_runs(10) == 1 and prod.diagnosis_runs(10) == 0
    assert Producers(s.conn, "f1", infos(), outbox).diagnosis_runs(10) == 0  # restarted
    (m,) = outbox.peek(10)
    doc = json.loads(m.payload)
    assert (m.key, m.idem) == ("serra/f1/north/diagnosis", f"f1/north/diagnosis/{int(EPOCH)}")
    assert s.conn.execute("SELECT kind, t FROM outbox WHERE id=?", (m.id,)).fetchone() == (
        "diagnosis", EPOCH)  # what history queries select by
    assert validate.errors(doc) == []
    assert (doc["succeeded"]["value"], doc["summary"]["value"], doc["runNotes"]["value"]) == (
        True, first.note, notes)
    failed = DiagnosisRun("north", EPOCH + 86400, False, "diagnosis abandoned after 1800 s")
    save_run(s.conn, failed)
    assert prod.diagnosis_runs(10) == -1  # the outbox is full: the run waits, its cursor stays
    outbox.mark_sent([m.id])
    assert prod.diagnosis_runs(10) == 1
    (m2,) = outbox.peek(10)
    assert json.loads(m2.payload)["succeeded"]["value"] is False
    s.set_meta("diagnosis_run/north", "{not json")
    outbox.mark_sent([m2.id])
    with caplog.at_level(logging.WARNING, logger="serra.gateway"):
        assert prod.diagnosis_runs(10) == 1 and prod.diagnosis_runs(10) == 0
    assert outbox.peek(10) == []
    (said,) = [r.getMessage() for r in caplog.records if r.name == "serra.gateway"]
    assert said.startswith("greenhouse north: the kept diagnosis run is not published, it "
                           "cannot be read: not JSON"), said
    off = Store(tmp_path / "off.db")
    save_run(off.conn, first)
    quiet = Producers(off.conn, "f1", infos(), Outbox(off.conn), diagnosis=False)
    assert quiet.run() == 0 and Outbox(off.conn).peek(10) == []
    off.close()
    s.close()


def test_trace_is_usable() -> None:
    assert np.isfinite(TRACE["t_in"]).mean() > 0.95


def test_a_ventilation_sensor_feeds_the_ventilation_messages(tmp_path: Path) -> None:
    """The hook the virtual ventilation sensor plugs into: whatever gives flow and heat loss each
    minute is stored and published as ``ventilation`` (a stand-in sensor here)."""
    from gateway.service.ventilation import VentilationEstimate, VentilationSensor

    calls = []

    def sensor(t, drivers, fluxes):
        calls.append((t, sorted(fluxes)))
        return VentilationEstimate(0.002, fluxes["q_loss"], out_of_range=t > EPOCH + 600)

    s = Store(tmp_path / "g.db")
    outbox = Outbox(s.conn)
    prod = Producers(s.conn, "f1", infos(), outbox)
    fill(s, range(20))
    pl = GreenhousePipeline("north", GH, MODEL, 7, 7, None,
                            ventilation=VentilationSensor(sensor, MODEL))
    pl.resume(s.conn)
    pl.step_pending(s.conn, end(19), 0.0, 600.0)
    assert calls and calls[0][1] == ["q_cnv_cnd", "q_loss", "q_solar", "q_thermal"]
    prod.run()
    vent = [json.loads(m.payload) for m in outbox.peek(1000) if m.key.endswith("/ventilation")]
    assert len(vent) == len(calls)
    assert vent[0]["ventilationFlow"]["value"] == 0.002
    assert vent[-1]["outOfTrainingRange"]["value"] is True
    for doc in vent:
        assert validate.errors(doc) == []


def test_the_shipped_virtual_sensor_plugs_into_the_service() -> None:
    """ventilation.load_ventilation wraps the real ONNX sensor for the model kind it was trained
    on: finite, non-negative flows with their heat loss each minute, flagged steps published as
    out of range; the shipped almeria-kind sensor is refused, naming t_soil (a kit has none)."""
    import pytest

    from gateway.service.ventilation import load_ventilation
    from gateway.vsensor.features import feature_names
    from gateway.vsensor.models import shipped_model
    from tests.vsensor_data import tiny_model

    gh = load_greenhouse("almeria-palmerillas")
    sensor = load_ventilation(tiny_model("prototype", kind="prototype"), gh)
    assert sensor.model.name == "prototype"
    step = sensor.step
    fluxes = dict.fromkeys(feature_names("prototype")[3:], 0.01)
    drivers = {"t_in": 24.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 55.0, "wind": 2.0}
    out = [step(EPOCH + 60.0 * k, drivers, fluxes) for k in range(10)]
    out.append(step(EPOCH + 3600.0, drivers, fluxes))  # after a gap: the history restarts
    for est in out:
        assert math.isfinite(est.flow) and est.flow >= 0.0 and math.isfinite(est.heat_loss)
    assert out[-1].heat_loss >= 0.0  # warmer inside: the house loses heat through its vents
    missing = step(EPOCH + 3660.0, {**drivers, "t_in": math.nan}, fluxes)
    assert missing.out_of_range and math.isfinite(missing.flow)
    with pytest.raises(ValueError, match="'almeria' model, which needs t_soil"):
        load_ventilation(shipped_model("almeria"), gh)

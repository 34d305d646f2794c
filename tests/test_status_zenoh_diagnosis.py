"""The daily diagnosis's last run on the status screen over Zenoh: the gateway publishes each
kept run (kind ``diagnosis``), the Zenoh source reads the newest of each greenhouse from the
gateway's history and shows the same lines as the store source; a run with warnings or a failed
run asks for attention either way; a switched-off diagnosis shows no run. Real parts: a SQLite
store, the gateway's producers and history queryable on a Zenoh session on 127.0.0.1 (port from
the OS), the screen's own session; every session is closed by the test."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.publish import validate, zconfig
from gateway.publish.history import HistoryQueryable
from gateway.publish.payloads import Place
from gateway.service.diagnosis import DiagnosisRun, save_run
from gateway.service.producers import GreenhouseInfo, Producers
from gateway.status import snapshot as S
from gateway.status.render import gateway_lines
from gateway.status.store_source import StoreSource
from gateway.status.zenoh_source import ZenohSource
from gateway.store import Store
from gateway.store.live import set_status
from gateway.store.outbox import Outbox
from tests.gateway_harness import EPOCH, wait_for

WARNED = DiagnosisRun(
    "north", EPOCH + 86400, True, "diagnosis of 1.8 days in 11 s: 0 finding(s)", 0,
    [{"code": "site_time_mismatch", "level": "warning",
      "message": "the kit's daylight falls in the site's night"},
     {"code": "short_heldout", "level": "note", "message": "too few held-out days"}])
FAILED = DiagnosisRun("north", EPOCH + 2 * 86400, False, "diagnosis abandoned after 1800 s")


class Gateway:
    """The gateway's store side (producers on a real SQLite file) and its history queryable on
    a real Zenoh session; ``keep`` does what the scheduler and the worker do after a run."""

    def __init__(self, db: Path) -> None:
        gh = load_greenhouse("biskra-prototype")
        model = build_model("prototype", gh)
        lo, hi = model.bounds(gh)
        self.store = Store(db)
        self.producers = Producers(self.store.conn, "f1", {"north": GreenhouseInfo(
            Place("f1", "north", 34.85, 5.73), 7, 7, model, lo.tolist(), hi.tolist())},
            Outbox(self.store.conn))
        before = zconfig.listening_ports()
        self.session = zenoh.open(zconfig.build(listen=["tcp/127.0.0.1:0"]))
        (self.endpoint,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
        self.history = HistoryQueryable(self.session, db, "f1")

    def keep(self, run: DiagnosisRun) -> None:
        save_run(self.store.conn, run)  # the scheduler
        assert self.producers.run() == 1  # the worker: one diagnosis message
        set_status(self.store.conn, {"diagnosis": {run.greenhouse: run.row()}}, run.when)

    def close(self) -> None:
        self.history.close()
        self.session.close()
        self.store.close()


@pytest.fixture
def gateway(tmp_path: Path) -> Iterator[Gateway]:
    gw = Gateway(tmp_path / "gw.db")
    try:
        yield gw
    finally:
        gw.close()


def diagnosis_lines(snap: S.Snapshot) -> list[str]:
    """The gateway panel's diagnosis lines, as the screen prints them."""
    lines = [t.plain for t in gateway_lines(snap)]
    return [x for x in lines if x.startswith("Diagnosis  ") or x.startswith("           warning")]


def store_snapshot(db: Path) -> S.Snapshot:
    src = StoreSource(db)
    try:
        return src.snapshot()
    finally:
        src.close()


def test_the_screen_over_zenoh_shows_the_last_run_as_the_store_does(
        gateway: Gateway, tmp_path: Path) -> None:
    db = tmp_path / "gw.db"
    gateway.keep(WARNED)
    (payload,) = [json.loads(p) for p, in gateway.store.conn.execute(
        "SELECT payload FROM outbox WHERE kind='diagnosis'")]
    assert validate.errors(payload) == []
    source = ZenohSource([gateway.endpoint])
    try:
        shown = wait_for(lambda: source.snapshot().gateway.diagnosis.get("north"), 60,
                         "the screen to read the run from the gateway's history")
        local = store_snapshot(db)
        assert shown == local.gateway.diagnosis["north"]
        assert shown.ok and shown.warnings == (("site_time_mismatch", WARNED.notes[0]["message"]),)
        snap = source.snapshot()
        assert diagnosis_lines(snap) == diagnosis_lines(local)
        assert diagnosis_lines(snap)[:2] == [  # cut to the screen's width, at a word
            "Diagnosis  north: last run 2009-11-02 06:00 ok, 0 findings (diagnosis of 1.8 …",
            "           warning site_time_mismatch: the kit's daylight falls in the …"]
        assert "diagnosis of north warns: site_time_mismatch" in S.attention(snap)
        assert not [a for a in S.attention(snap) if "failed" in a]

        gateway.keep(FAILED)  # the next run fails: the newest message is the one shown
        shown = wait_for(lambda: (d := source.snapshot().gateway.diagnosis.get("north")) and
                         not d.ok and d, 60, "the screen to show the failed run")
        local = store_snapshot(db)
        assert shown == local.gateway.diagnosis["north"]
        snap = source.snapshot()
        (line,) = diagnosis_lines(snap)
        assert diagnosis_lines(local) == [line]
        assert line == ("Diagnosis  north: last run 2009-11-03 06:00 failed, 0 findings "
                        "(diagnosis …")  # cut at a word
        assert [a for a in S.attention(snap) if "diagnosis" in a] == ["diagnosis of north failed"]
    finally:
        source.close()


def test_a_switched_off_diagnosis_shows_no_run_over_zenoh(gateway: Gateway) -> None:
    """The failed run stays in the gateway's history (for the cloud); once the gateway says
    its diagnosis is off (``status``: ``diagnosisEnabled`` false, as the store's empty status
    row says it), the screen shows no run and asks for nobody."""
    gateway.keep(FAILED)
    source = ZenohSource([gateway.endpoint])
    try:
        wait_for(lambda: "north" in source.snapshot().gateway.diagnosis, 60,
                 "the screen to show the failed run")
        made = gateway.producers.snapshots(FAILED.when + 60, 0.0,
                                           {"north": {"diagnosisEnabled": False}})
        assert made == 2  # status, device/7
        snap = wait_for(lambda: (s := source.snapshot()) and not s.gateway.diagnosis and s, 60,
                        "the screen to drop the run of a switched-off diagnosis")
        assert not [a for a in S.attention(snap) if "diagnosis" in a]
        assert diagnosis_lines(snap) == []
    finally:
        source.close()

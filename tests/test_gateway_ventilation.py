"""The virtual ventilation sensor in the live gateway (gateway/service/ventilation.py), on a real
SQLite file with the real config loader, worker set-up, pipelines and ONNX sensor (a tiny
prototype-kind model trained here, tests/vsensor_data.py, with a small estimator budget): a
greenhouse whose forecasting model is not the sensor's kind, or whose estimator settings are not
the ones the sensor was trained with, feeds the sensor from a second estimator of that kind and
those settings, with the same flows whatever the forecasting model; a sensor the kit cannot feed
is refused."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import pytest

from gateway.greenhouse import PRESET_DIR
from gateway.service.clock import WallClock
from gateway.service.config import ConfigError, load_config
from gateway.service.resources import prepare
from gateway.service.ventilation import STATE_KEY
from gateway.service.worker import Worker
from gateway.store import Store
from gateway.store.keys import write_keys
from gateway.vsensor.adaptive import settings_for
from gateway.vsensor.models import shipped_model
from tests.gateway_harness import EPOCH, KEY, sim_trace, store_trace
from tests.vsensor_data import TINY, rewrite_metadata, tiny_model

TRACE = sim_trace(days=0.5)  # 6 h from 06:00
VENTED = "prototype+vent_control"
HOUSE = (PRESET_DIR / "almeria-palmerillas.toml").read_text() + (
    "\n[online.t_in]\niterations = 10\nbats = 10\n")
"""The Almería house with a small forecasting estimator budget in its own ``[online.t_in]``
table (the live default is 50 × 20), as the pipeline tests' house: what these tests check (which
estimator feeds the sensor, equal flows, exact resumes) does not depend on the budget; the
sensor's own estimator keeps its TINY training settings, which still differ from it."""


@pytest.fixture(scope="module")
def sensor() -> Path:
    """A prototype-kind sensor (kit columns only), trained on the Almería house with vents on
    the fluxes of an estimator with the TINY budget (its metadata's online_overrides)."""
    return tiny_model("prototype", kind="prototype")


@pytest.fixture(scope="module")
def live_settings_sensor(sensor, tmp_path_factory) -> Path:
    """The same sensor as if trained with the live estimator's own settings (no overrides)."""
    return rewrite_metadata(sensor, tmp_path_factory.mktemp("live") / "live.onnx",
                            online_overrides={})


def write(folder: Path, models: dict[str, str], vsensor: Path) -> Path:
    """A gateway.toml with one greenhouse per (name, model), all on device 7, with ``vsensor``."""
    write_keys(folder / "keys.txt", {7: KEY})
    (folder / "house.toml").write_text(HOUSE)
    houses = "".join(f'[[greenhouse]]\nname = "{n}"\ngreenhouse = "{folder / "house.toml"}"\n'
                     f'model = "{m}"\ninside = 7\nvsensor = "{vsensor}"\n'
                     for n, m in models.items())
    path = folder / "gw.toml"
    path.write_text(f'[gateway]\nfarm = "f1"\ndb = "gw.db"\nkeys = "keys.txt"\n'
                    f'[estimator]\nseed = 1\n{houses}')
    return path


def fill(store: Store, minutes: range) -> None:
    """Records of the simulated trace, one per minute, stamped mid-minute."""
    store_trace(store, TRACE, minutes)


def start(cfg: Path, store: Store, caplog) -> Worker:
    """What ``run`` does before its loop: prepare, then the worker's set-up (pipelines resumed)."""
    worker = Worker(load_config(cfg), prepare(load_config(cfg)), WallClock(), lambda s: None)
    with caplog.at_level(logging.INFO, logger="serra.gateway"):
        worker._setup(store.conn)
    return worker


def step(worker: Worker, store: Store, k: int) -> None:
    for pl in worker.pipelines:
        pl.step_pending(store.conn, EPOCH + 60 * k + 31, 0.0, 600.0)


def flows(store: Store, greenhouse: str) -> dict[float, float]:
    return dict(store.conn.execute(
        "SELECT t, value FROM estimates WHERE greenhouse=? AND source='vsensor' "
        "AND name='ventilation_flow' ORDER BY t", (greenhouse,)).fetchall())


def same(a: dict, b: dict) -> bool:
    """Snapshots equal as saved (JSON: NaN equals NaN)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_a_vented_forecasting_model_runs_a_prototype_sensor_every_minute(tmp_path, sensor, caplog):
    """prototype+vent_control forecasts; the prototype-kind sensor still publishes every minute
    with a finite, non-negative flow; the published fluxes stay the forecasting model's."""
    store = Store(tmp_path / "gw.db")
    fill(store, range(61))
    worker = start(write(tmp_path, {"north": VENTED}, sensor), store, caplog)
    assert "ventilation sensor fed by its own 'prototype' estimator (its kind)" in caplog.text
    step(worker, store, 60)
    measured = [t for (t,) in store.conn.execute(
        "SELECT t FROM estimates WHERE source='measured' AND name='t_in' ORDER BY t")]
    got = flows(store, "north")
    assert len(measured) >= 55 and list(got) == measured  # one flow per minute with data
    assert all(math.isfinite(v) and v >= 0.0 for v in got.values())
    names = {n for (n,) in store.conn.execute("SELECT DISTINCT name FROM estimates "
                                              "WHERE source='flux'")}
    assert "q_vent_control" in names  # the forecasting model's fluxes, not the sensor's
    worker.producers.run()
    vent = [json.loads(m.payload) for m in worker.outbox.peek(1000)
            if m.key.endswith("/ventilation")]
    assert [d["ventilationFlow"]["value"] for d in vent] == list(got.values())


def test_the_sensor_is_fed_with_its_training_settings_whatever_the_forecasting_model(
        tmp_path, sensor, caplog):
    """A sensor trained on an estimator with other settings (TINY, not the live budget) gets its
    own estimator with those settings even where the forecasting model is its kind; the vented
    and the prototype greenhouse then publish exactly the same flows (same data, same seed)."""
    store = Store(tmp_path / "gw.db")
    fill(store, range(91))
    worker = start(write(tmp_path, {"plain": "prototype", "vented": VENTED}, sensor), store, caplog)
    assert "own 'prototype' estimator (its training settings)" in caplog.text
    trained = settings_for(worker.pipelines[0].model, worker.pipelines[0].gh, TINY)
    for pl in worker.pipelines:
        assert pl.vent is not None and pl.vent.own is not None
        assert pl.vent.own.settings == trained and pl.est.settings != trained
    step(worker, store, 90)
    plain, vented = flows(store, "plain"), flows(store, "vented")
    assert len(plain) >= 80 and vented == plain
    assert len(set(plain.values())) > 1  # the sensor moves with the data


def test_a_sensor_trained_on_the_live_settings_reads_the_forecasting_estimator(
        tmp_path, live_settings_sensor, caplog):
    """Same kind, same settings: one estimator, whose fluxes feed the sensor."""
    store = Store(tmp_path / "gw.db")
    fill(store, range(31))
    worker = start(write(tmp_path, {"plain": "prototype"}, live_settings_sensor), store, caplog)
    assert "fed by its own" not in caplog.text
    pl = worker.pipelines[0]
    assert pl.vent is not None and pl.vent.own is None
    step(worker, store, 30)
    assert len(flows(store, "plain")) >= 25


def test_the_sensors_estimator_resumes_with_the_forecasting_one(tmp_path, live_settings_sensor,
                                                                caplog):
    """A restart resumes both estimators exactly (the sensor's rides in the saved state); a
    greenhouse moved from ``prototype`` to the vented model resumes the sensor's estimator from
    the saved prototype estimator, and its forecasting state is migrated as before."""
    whole, split = Store(tmp_path / "whole.db"), Store(tmp_path / "split.db")
    fill(whole, range(91))
    fill(split, range(46))  # the records up to the switch: the restart is a real one
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    cfg_a = write(tmp_path / "a", {"north": VENTED}, live_settings_sensor)
    ref = start(cfg_a, whole, caplog)
    step(ref, whole, 90)
    cfg_b = write(tmp_path / "b", {"north": "prototype"}, live_settings_sensor)
    first = start(cfg_b, split, caplog)
    step(first, split, 45)
    saved = json.loads(split.conn.execute("SELECT state FROM estimator_state").fetchone()[0])
    assert STATE_KEY not in saved  # one estimator while kind and settings agree
    fill(split, range(46, 91))
    caplog.clear()
    cfg_b.write_text(cfg_b.read_text().replace('"prototype"', f'"{VENTED}"'))
    second = start(cfg_b, split, caplog)
    assert "ventilation sensor's 'prototype' estimator resumed from the saved forecasting" in caplog.text
    step(second, split, 90)
    own = second.pipelines[0].vent
    ref_own = ref.pipelines[0].vent
    assert own is not None and own.own is not None and ref_own is not None and ref_own.own is not None
    # the sensor's estimator saw the same minutes either way: the same state
    assert same(own.own.snapshot(), ref_own.own.snapshot())
    caplog.clear()
    third = start(cfg_b, split, caplog)
    assert "ventilation sensor's 'prototype' estimator resumed" in caplog.text
    assert same(third.pipelines[0].est.snapshot(), second.pipelines[0].est.snapshot())
    third_own = third.pipelines[0].vent
    assert third_own is not None and third_own.own is not None
    assert same(third_own.own.snapshot(), own.own.snapshot())


def test_a_restart_resumes_the_sensors_closed_loop(tmp_path, sensor, caplog):
    """Stopped after 45 minutes and started again, the gateway publishes the same flows as one
    that ran through: the sensor's history (filters, delays, fed-back outputs) is saved with the
    estimators' state and resumed, not settled again from nothing."""
    whole, split = Store(tmp_path / "whole.db"), Store(tmp_path / "split.db")
    fill(whole, range(91))
    fill(split, range(46))  # the kit's records up to the stop: the stop is a real one
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    step(start(write(tmp_path / "a", {"north": VENTED}, sensor), whole, caplog), whole, 90)
    cfg = write(tmp_path / "b", {"north": VENTED}, sensor)
    step(start(cfg, split, caplog), split, 45)
    assert max(flows(split, "north")) < max(flows(whole, "north"))
    fill(split, range(46, 91))
    caplog.clear()
    step(start(cfg, split, caplog), split, 90)
    assert "ventilation sensor's history resumed" in caplog.text
    ran, restarted = flows(whole, "north"), flows(split, "north")
    assert len(ran) >= 80 and restarted == ran


def test_the_shipped_prototype_sensor_runs_live_on_kit_columns_every_minute(tmp_path, caplog):
    """The shipped prototype-kind sensor (kit inputs, trained with vpd_in, the almeria model's
    flow as target) on the kit's records alone (no t_soil): its own prototype estimator with its
    training settings feeds it, one finite, non-negative flow per minute with data."""
    assert "t_soil" not in TRACE
    store = Store(tmp_path / "gw.db")
    fill(store, range(61))
    worker = start(write(tmp_path, {"north": VENTED}, shipped_model("prototype")), store, caplog)
    assert "ventilation sensor fed by its own 'prototype' estimator" in caplog.text
    step(worker, store, 60)
    measured = [t for (t,) in store.conn.execute(
        "SELECT t FROM estimates WHERE source='measured' AND name='t_in' ORDER BY t")]
    got = flows(store, "north")
    assert len(measured) >= 55 and list(got) == measured
    assert all(math.isfinite(v) and v >= 0.0 for v in got.values())
    assert len(set(got.values())) > 1  # it moves with the data


def test_a_sensor_the_kit_cannot_feed_is_refused_naming_the_key_and_column(tmp_path, caplog):
    """The shipped almeria-kind sensor reads the almeria model's fluxes, which need t_soil."""
    cfg = write(tmp_path, {"north": VENTED}, shipped_model("almeria"))
    with pytest.raises(ConfigError) as e:
        prepare(load_config(cfg))
    msg = str(e.value)
    assert "greenhouse[1].vsensor" in msg and "t_soil" in msg and "'almeria'" in msg, msg

"""A saved estimator state of one model resumed by the other (``model =`` changed between
``prototype`` and ``prototype+vent_control``): the states are real ones, saved by the live
gateway's pipeline in a real SQLite store after stepping the reference simulator's kit trace."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gateway.estimate.online import OnlineEstimator, online_settings
from gateway.estimate.state_migration import migrate_state
from gateway.model import VENTED_PROTOTYPE, build_model
from gateway.service.pipeline import GreenhousePipeline
from gateway.store import Store
from tests.gateway_harness import EPOCH
from tests.test_gateway_pipeline import GH, end, fill, rows

SUNRISE = 100  # [min after EPOCH, 06:00Z] the trace's sun is up (> 5 W m-2) from about here


def pipeline(model: str, theta0: np.ndarray | None = None) -> GreenhousePipeline:
    """The snapshot saved with every batch (``snapshot_every_min`` 1): these tests read and edit
    the saved snapshot, which must then be the state at the cursor, whatever the batches."""
    return GreenhousePipeline("north", GH, build_model(model, GH), 7, 7, theta0, seed=1,
                              snapshot_every_min=1)


def saved(store: Store) -> dict:
    return json.loads(store.conn.execute("SELECT state FROM estimator_state").fetchone()[0])


def run_then_switch(tmp_path: Path, first: str, second: str, minutes: int,
                    theta0: np.ndarray | None = None,
                    ran: Path | None = None) -> tuple[Store, dict, GreenhousePipeline, str]:
    """``first`` steps ``minutes`` minutes and saves; a gateway restarted with ``second``
    resumes from the same store file. ``ran``: a closed store file in which that run was made
    already (``prototype_hour``), resumed from a copy of it."""
    if ran is not None:
        shutil.copyfile(ran, tmp_path / "serra.db")
    store = Store(tmp_path / "serra.db")
    if ran is None:
        fill(store, range(minutes + 1))
        a = pipeline(first)
        a.resume(store.conn)
        a.step_pending(store.conn, end(minutes), 0.0, 600.0)
    before = saved(store)
    assert before["model"] == first and before["counters"]["samples"] == minutes
    b = pipeline(second, theta0)
    return store, before, b, b.resume(store.conn)


@pytest.fixture(scope="module")
def prototype_hour(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A closed store file in which the prototype stepped the first 60 minutes and saved its
    state: made once for the three tests that resume such a state (each on its own copy)."""
    store = Store(tmp_path_factory.mktemp("prototype-hour") / "serra.db")
    fill(store, range(61))
    a = pipeline("prototype")
    a.resume(store.conn)
    a.step_pending(store.conn, end(60), 0.0, 600.0)
    store.close()  # the last connection: SQLite folds the WAL into the file, which is then whole
    return store.path


def test_a_prototype_state_resumes_in_the_vented_model(tmp_path: Path) -> None:
    store, before, b, line = run_then_switch(tmp_path, "prototype", VENTED_PROTOTYPE, 150)
    # one line names the change: what was kept, what starts where, what was dropped
    assert "resumed" in line and "starting anew" not in line
    assert ("migrated from model 'prototype' to 'prototype+vent_control': kept c_solar, "
            "c_cnv_cnd, c_loss, c_thermal") in line
    assert "new at their initial values: c_vc = 0.0005, t_vc = 25; dropped: none" in line
    # the adapted parameters are kept to the bit (no silent reset), the new ones start where a
    # new estimator would (the middle of their hard box: no params file)
    np.testing.assert_array_equal(b.est.theta[:4], before["theta"])
    assert before["theta"] != build_model("prototype", GH).defaults(GH)[:4].tolist()
    np.testing.assert_array_equal(b.est.theta[4:], [5e-4, 25.0])
    assert b.est.counters.samples == 150 and b.cursor == EPOCH + 60 * 149
    assert b.forecaster.kf is not None and b.forecaster.kf.estimate() is not None  # filter kept
    # and it goes on: the new parameters are estimated in the sun and saved under the new model
    fill(store, range(151, 260))
    rep = b.step_pending(store.conn, end(259), 0.0, 600.0)
    assert rep.stepped == 109 and rep.restarts == 0
    after = saved(store)
    assert after["model"] == VENTED_PROTOTYPE and len(after["theta"]) == 6
    assert after["counters"]["samples"] == 259
    assert after["theta"][4:] != [5e-4, 25.0]  # c_vc, t_vc adapted after the sun came up
    assert {r[2] for r in rows(store, "online") if r[0] > EPOCH + 60 * 149} >= {"c_vc", "t_vc"}
    assert len(rows(store, "forecast")) > 3 * 100


def test_a_vented_state_resumes_in_the_prototype(tmp_path: Path) -> None:
    store, before, a, line = run_then_switch(tmp_path, VENTED_PROTOTYPE, "prototype",
                                             SUNRISE + 80)
    assert "migrated from model 'prototype+vent_control' to 'prototype'" in line
    assert "new at their initial values: none; dropped: c_vc, t_vc" in line
    np.testing.assert_array_equal(a.est.theta, before["theta"][:4])
    assert before["theta"][4:] != [5e-4, 25.0]  # the dropped ones had been adapted
    fill(store, range(SUNRISE + 81, SUNRISE + 120))
    a.step_pending(store.conn, end(SUNRISE + 119), 0.0, 600.0)
    after = saved(store)
    assert after["model"] == "prototype" and after["names"] == build_model("prototype", GH).names


def test_new_parameters_start_from_the_params_file_values(tmp_path: Path,
                                                         prototype_hour: Path) -> None:
    """With a params file the new parameters start at its values (the estimator's theta0)."""
    theta0 = build_model(VENTED_PROTOTYPE, GH).defaults(GH)
    theta0[4:] = [2e-4, 22.0]
    _, before, b, line = run_then_switch(tmp_path, "prototype", VENTED_PROTOTYPE, 60, theta0,
                                         prototype_hour)
    assert "c_vc = 0.0002, t_vc = 22" in line
    np.testing.assert_array_equal(b.est.theta, before["theta"] + [2e-4, 22.0])


def test_an_unrelated_model_is_not_migrated() -> None:
    """The almeria model's c_loss is a flow [m3 s-1], the prototype's a flow per floor area
    [m s-1]: the same name, another quantity. Nothing matches, so nothing is carried."""
    from tests.test_online import ALMERIA, FAST, model_data, samples
    from tests.test_online import GH as ALMERIA_GH

    est = OnlineEstimator(ALMERIA, ALMERIA_GH, settings=online_settings(ALMERIA, ALMERIA_GH, FAST))
    for s in list(samples(model_data(ALMERIA, ALMERIA_GH, hours=0.5)))[:20]:
        est.update(s)
    proto = build_model("prototype", ALMERIA_GH)
    with pytest.raises(ValueError, match="shares no parameter"):
        migrate_state(est.snapshot(), proto, ALMERIA_GH, proto.defaults(ALMERIA_GH))


def test_an_unusable_state_starts_anew_with_a_line_saying_so(tmp_path: Path,
                                                            prototype_hour: Path) -> None:
    store, before, _, _ = run_then_switch(tmp_path, "prototype", "prototype", 60,
                                          ran=prototype_hour)
    before["model"] = "no-such-model"
    store.conn.execute("UPDATE estimator_state SET state=?", (json.dumps(before),))
    b = pipeline(VENTED_PROTOTYPE)
    line = b.resume(store.conn)
    assert "saved estimator state not used" in line and "no-such-model" in line
    assert b.est.counters.samples == 0


def test_a_restore_that_fails_half_way_leaves_a_new_estimator(tmp_path: Path,
                                                             prototype_hour: Path) -> None:
    """The estimator's part restores, the forecaster's is broken: the line says the state was not
    used, and nothing of it is left behind (before, the estimator kept the restored parameters and
    counters under a line saying it started anew)."""
    store, before, _, _ = run_then_switch(tmp_path, "prototype", "prototype", 60,
                                          ran=prototype_hour)
    before["forecaster"]["disturbance"]["state"] = [1.0, 2.0]  # three of five values missing
    store.conn.execute("UPDATE estimator_state SET state=?", (json.dumps(before),))
    for model in ("prototype", VENTED_PROTOTYPE):
        b = pipeline(model)
        line = b.resume(store.conn)
        assert "saved estimator state not used" in line and "starting anew" in line
        assert b.est.counters.samples == 0 and b.forecaster.kf is not None
        assert b.forecaster.kf.estimate() is None
        np.testing.assert_array_equal(b.est.theta, b.est.theta0)

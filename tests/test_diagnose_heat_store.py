"""The added heat store (gateway/diagnose/heat_store.py): neutral at zero amplitude, its observer
is the model's own recursion, and the diagnosis finds it on data the model itself made."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import diagnose
from gateway.diagnose.effects import EFFECTS, HEAT_STORE, compose
from gateway.diagnose.fit import drivers
from gateway.diagnose.structure import structure
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.series import Series

DAY = 86400.0
DT = 300.0
E = HEAT_STORE


def _data(days: int = 8, seed: int = 3) -> tuple[Series, np.random.Generator]:
    """5-minute kit-like drivers with day-to-day weather (as tau_profile.py --synthetic)."""
    n = days * 288
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    day = t / DAY
    daily = np.repeat(np.arange(days + 1), 288)[:n]
    cols = {"t_out": 10 + 5 * np.sin(2 * np.pi * (day % 1 - 0.3)) + rng.normal(0, 3, days + 1)[daily],
            "rh_out": np.full(n, 70.0), "rh_in": np.full(n, 60.0), "t_in": np.full(n, 12.0),
            "i_glob": np.maximum(0, 600 * np.sin(2 * np.pi * (day % 1 - 0.25)))
            * rng.uniform(0.2, 1.0, days + 1)[daily], "wind": rng.uniform(0.5, 6.0, days + 1)[daily]}
    t64 = np.datetime64("2020-01-01T00:00:00") + t.astype("timedelta64[s]")
    return Series(t64, DT, cols), rng


def _models(store: bool):
    gh = load_greenhouse("biskra-prototype")
    m0 = structure(build_model("prototype", gh), gh, store)
    return gh, m0


def _on_a_sine(store: bool):
    """3 days of drivers whose reading is a sine plus noise, the base (with or without its own
    store) and the base plus the added store: (gh, base, model, drivers, rows)."""
    gh, m0 = _models(store)
    s, rng = _data(days=3)
    x = drivers(s, gh)
    n = len(s)
    x["t_in"] = 14 + 4 * np.sin(np.arange(n) / 40.0) + rng.normal(0, 0.1, n)
    return gh, m0, compose(m0, [E], gh, float(x["_index"][-1])), x, n


@pytest.mark.parametrize("store", [False, True])
def test_zero_store_is_the_base_model_exactly(store):
    gh, m0, m, x, _ = _on_a_sine(store)
    th0 = m0.defaults(gh)
    th = m.defaults(gh)  # c_added = 0 (neutral)
    th[m.index(E.tau_name)] = 0.8 * DAY
    assert th[m.index(E.amp_name)] == 0.0
    np.testing.assert_array_equal(m.free_run(th[None], x, gh, DT), m0.free_run(th0[None], x, gh, DT))
    np.testing.assert_array_equal(m.one_step(th[None], x, gh, DT), m0.one_step(th0[None], x, gh, DT))
    starts = np.array([10, 300, 600])
    np.testing.assert_array_equal(m.shoot(th[None], x, gh, DT, starts, 24),
                                  m0.shoot(th0[None], x, gh, DT, starts, 24))


def test_store_observer_is_the_steps_recursion_on_the_reading():
    """Observer rows (different C_w, h_w, τ) = the store's own step driven by the reading."""
    gh, m0, m, x, n = _on_a_sine(False)
    rows = np.repeat(m.defaults(gh)[None], 3, axis=0)
    rows[:, m.index(E.amp_name)] = [2e4, 1.6e5, 4e5]
    rows[:, m.index("t_added")] = [2000.0, 8 * 3600.0, 700.0]
    rows[:, m.index(E.tau_name)] = [0.5 * DAY, 1.3 * DAY + 100.0, 0.0]
    got = m.added.observer(m, m.columns(rows), x, DT)
    ta = x["t_in"]
    for i, row in enumerate(rows):
        tw, tau = row[m.index("t_added")], row[m.index(E.tau_name)]
        lam = np.exp(-DT / tw)
        y = np.empty(n)
        y[0] = ta[0]
        for t in range(n - 1):  # the step from t sees the new air; before τ the store is the air
            y[t + 1] = lam * y[t] + (1 - lam) * ta[t + 1] if x["_index"][t] >= tau else ta[t + 1]
        np.testing.assert_allclose(got[i], y, rtol=0, atol=1e-9)


def test_diagnosis_names_an_added_store_on_model_made_data():
    """8 days made by the structured prototype with 30 kg m-2 of water (C_w = 1.26e5 J m-2
    K-1, h_w = 5 W m-2 K-1: a 7 h store) added from day 3.4, reading noise 0.08 K; the whole
    diagnosis (split 0.5) with the capacity factor and a heat source as rivals names the store
    first, its start within 3 h and C_w within 15 % (measured: -0.1 h, -4.7 %)."""
    gh, m0 = _models(False)
    s, rng = _data()
    x = drivers(s, gh)
    n = len(s)
    m = compose(m0, [E], gh, float(x["_index"][-1]))
    truth, tau = m.defaults(gh), 3.4 * DAY
    truth[m.index(E.amp_name)], truth[m.index(E.tau_name)] = 1.26e5, tau
    truth[m.index("t_added")] = 1.26e5 / 5.0  # C_w / h_w
    clean = m.free_run(truth[None], x, gh, DT)[0]
    base_run = m0.free_run(m0.defaults(gh)[None], {**x, "t_in": clean}, gh, DT)[0]
    assert np.nanmax(np.abs(clean - base_run)) > 0.5  # the store shows in the data
    cols = dict(s.columns) | {"t_in": clean + rng.normal(0, 0.08, n)}
    library = (EFFECTS["thermal_mass"], EFFECTS["heat_source"], E)
    d = diagnose(Series(s.time, DT, cols), gh, build_model("prototype", gh), library=library)
    assert d.findings and d.findings[0].effect is E
    f = d.findings[0]
    assert abs(f.tau - tau) <= 3 * 3600.0
    assert f.amplitude == pytest.approx(1.26e5, rel=0.15)
    assert f.trace_unit == "W m-2" and np.all(f.trace[: int(tau // DT)] == 0.0)


def test_runs_with_a_store_agree():
    """shoot from a start = free run from it, with the store on before and after the start."""
    gh, m0, m, x, n = _on_a_sine(True)
    rows = np.repeat(m.defaults(gh)[None], 2, axis=0)
    rows[:, m.index("h_store")] = 3.0
    rows[:, m.index(E.amp_name)] = [6e4, 2e5]
    rows[:, m.index("t_added")] = [3 * 3600.0, 20 * 3600.0]
    rows[:, m.index(E.tau_name)] = [0.5 * DAY, 1.1 * DAY]
    starts = np.array([100, 300])  # 0.35 d and 1.04 d: before and after each start time
    shot = m.shoot(rows, x, gh, DT, starts, 48)
    for i in range(2):
        for j, a in enumerate(starts):
            run = m.free_run(rows[i : i + 1], x, gh, DT, start=int(a), stop=int(a) + 49)[0]
            np.testing.assert_allclose(shot[i, j], run[1:], rtol=0, atol=1e-9)
    assert np.nanmax(np.abs(shot[0] - shot[1])) > 0.05  # the stores differ

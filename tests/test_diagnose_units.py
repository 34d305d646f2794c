"""Unit checks of the diagnosis's structured base: the base at neutral values, effect terms,
the heat store, sensor terms and the base's optional parts (the search's tools:
test_diagnose_search_units.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gateway.diagnose.effects import EFFECTS, compose
from gateway.diagnose.fit import drivers
from gateway.diagnose.structure import STORE, structure
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.model import psychrometrics as psy
from tests.diagnose_data import prototype_bases, sine_series


def test_structured_base_at_neutral_values_is_the_thesis_model():
    """m_cap = 1, no store: the diagnosis's base runs exactly like gateway.model's (with the
    same integration)."""
    gh, base, m = prototype_bases()
    s = sine_series()
    x = drivers(s, gh)
    th = m.defaults(gh)
    np.testing.assert_allclose(m.free_run(th[None], x, gh, 60.0)[0],
                               base.free_run(base.defaults(gh)[None], x, gh, 60.0)[0], atol=1e-9)
    np.testing.assert_allclose(m.one_step(th[None], x, gh, 60.0)[0, 1:],
                               base.one_step(base.defaults(gh)[None], x, gh, 60.0)[0, 1:], atol=1e-9)


def test_thermal_mass_effect_scales_capacity_from_its_start():
    """thermal_mass with factor 3 from τ: identical to a model of 3 × capacity after τ."""
    gh, base, m0 = prototype_bases()
    s = sine_series()
    x = drivers(s, gh)
    m = compose(m0, [EFFECTS["thermal_mass"]], gh, x["_index"][-1])
    th = m.defaults(gh)
    th[m.index("m_capacity")] = 3.0
    th[m.index("tau_thermal_mass")] = 600 * 60.0
    run = m.free_run(th[None], x, gh, 60.0)[0]
    plain = base.free_run(base.defaults(gh)[None], x, gh, 60.0)[0]
    np.testing.assert_allclose(run[:601], plain[:601], atol=1e-9)
    scaled = replace(base, capacity=lambda g: 3.0 * base.capacity(g))
    tail = scaled.free_run(base.defaults(gh)[None], {**x, "t_in": np.r_[np.zeros(600), run[600:]]},
                           gh, 60.0, start=600)[0]
    np.testing.assert_allclose(run[600:], tail, atol=1e-9)


def test_store_observer_matches_the_sequential_recursion():
    gh, base, m = prototype_bases(store=True)
    s = sine_series(n=1500)
    x = drivers(s, gh)
    rng = np.random.default_rng(1)
    x["t_in"] = 15 + 5 * np.sin(np.arange(1500) / 200.0) + rng.normal(0, 0.1, 1500)
    th = m.defaults(gh)
    rows = np.repeat(th[None], 2, axis=0)
    rows[:, m.index("c_store")] = [1e4, 2e5]
    rows[:, m.index("h_store")] = [20.0, 2.0]
    rows[:, m.index("a_store")] = [0.3, 0.1]
    got = m.observer(m.columns(rows), x, 60.0)
    for i, row in enumerate(rows):
        p = dict(zip(m.names, row, strict=True))
        k, h, c = p["k_store"], p["h_store"], p["c_store"]
        lam = np.exp(-(h + k) * 60.0 / c)
        ta_next = np.r_[x["t_in"][1:], x["t_in"][-1]]
        u = (p["a_store"] * x["i_glob"] + h * ta_next + k * x["t_out"]) / (h + k)
        y = np.empty(1500)
        y[0] = u[0]
        for t in range(1499):
            y[t + 1] = lam * y[t] + (1 - lam) * u[t]
        np.testing.assert_allclose(got[i], y, rtol=1e-9, atol=1e-9)


def test_store_shifts_heat_into_the_night():
    """A store that absorbs sun by day keeps the night warmer than the same model without it."""
    gh, base, m = prototype_bases(store=True)
    s = sine_series()
    x = drivers(s, gh)
    th = m.defaults(gh)
    th[m.index("h_store")], th[m.index("a_store")], th[m.index("k_store")] = 5.0, 0.3, 0.0
    off = th.copy()
    off[m.index("a_store")] = 0.0
    night = (np.arange(2880) % 1440) > 1200  # 20:00-24:00
    warm = m.free_run(th[None], x, gh, 60.0)[0]
    cold = m.free_run(off[None], x, gh, 60.0)[0]
    assert np.all(warm[night] - cold[night] > 0.1)


def test_sensor_drift_changes_reading_not_state():
    gh, base, m0 = prototype_bases()
    s = sine_series()
    x = drivers(s, gh)
    m = compose(m0, [EFFECTS["sensor_drift"]], gh, x["_index"][-1])
    th = m.defaults(gh)
    th[m.index("a_drift")] = 1.0
    th[m.index("tau_sensor_drift")] = 1440 * 60.0
    run = m.free_run(th[None], x, gh, 60.0)[0]
    plain = base.free_run(base.defaults(gh)[None], x, gh, 60.0)[0]
    np.testing.assert_allclose(run[:1441], plain[:1441], atol=1e-9)
    np.testing.assert_allclose(run[-1] - plain[-1], 1.0 * 1439 / 1440, atol=1e-9)


def test_electronic_offset_recomputes_the_vapour_pressure():
    """A drifting temperature reading (RH referring to the true air) must not distort the
    vapour pressure the transpiration term sees (Almería model, III.29)."""
    gh = load_greenhouse("almeria-palmerillas")
    base = build_model("almeria", gh)
    m0 = structure(base, gh, store=False)
    s = sine_series()
    s.columns["t_soil"] = np.full(len(s), 15.0)
    x = drivers(s, gh)
    m = compose(m0, [EFFECTS["sensor_drift"]], gh, x["_index"][-1])
    th = m.defaults(gh)
    th[m.index("a_drift")] = 2.0
    t = np.array([[2000]])
    view = m._inputs(m.columns(th[None]), x, t)
    offset = 2.0 * 2000 * 60 / 86400
    want = psy.vapour_pressure(x["t_in"][2000] - offset, x["rh_in"][2000])
    np.testing.assert_allclose(view["p_w_in"][t], want)
    assert abs(view["p_w_in"][t] - x["p_w_in"][2000]).max() > 0.01


def test_store_parameters_are_bounded_and_physical():
    for p in STORE:
        assert p.lower <= p.default <= p.upper and p.lower >= 0.0


def test_vents_opened_above_a_setpoint_are_kept_in_the_base():
    """Data from the structured prototype + vents a controller opens above 24 °C (hot sunny
    days, T_in well above it): the base structure keeps the vent controller part, which cuts the
    inner validation error, and finds the setpoint; a house without one does not keep it."""
    from gateway.diagnose.base import calibrate_base
    from gateway.model.vent_control import ControlledVentilation

    gh, _, m = prototype_bases()
    s = sine_series(n=2016, step=300)  # 7 days
    s.columns["t_out"] = s.columns["t_out"] + 14.0  # a summer: 19-29 °C outside
    x = drivers(s, gh)
    vented = m.with_terms(ControlledVentilation(gh.air_density))
    truth = vented.defaults(gh)
    truth[vented.index("c_vc")], truth[vented.index("t_vc")] = 4e-4, 24.0
    for model, theta, want in ((vented, truth, True), (m, m.defaults(gh), False)):
        x["t_in"] = model.free_run(theta[None], x, gh, 300.0)[0]
        got, th, log = calibrate_base(m, gh, x, 300.0, 1344, 72, 0, lambda msg: None)
        (vc,) = [e for e in log if e["structure"] == "vent controller"]
        assert vc["kept"] is want, log
        if want:
            assert vc["validation_mse"] < 0.5 * log[0]["validation_mse"]
            assert abs(th[got.index("t_vc")] - 24.0) < 1.0


def test_wide_vent_box_lets_the_base_follow_a_summer_house_vents(monkeypatch):
    """A summer house whose vents exchange ~5 air changes an hour per kelvin above the setpoint
    (C_vc = 5e-3 m s-1 K-1, data from the structured prototype): with ``base.WIDE_VENT_BOX``
    the vent controller part's rate C_vc / m_cap is fitted near the truth inside its physical
    box; with the term's own box (1e-3, and m_cap ≥ 1) it sits on that bound and the base
    extrapolates worse (docs/effects.md, "The summer base (issue 10)")."""
    from gateway.diagnose import base
    from gateway.model.vent_control import ControlledVentilation

    gh, _, m = prototype_bases()
    s = sine_series(n=2016, step=300)  # 7 days
    s.columns["t_out"] = s.columns["t_out"] + 14.0  # a summer: 19-29 °C outside
    x = drivers(s, gh)
    vented = m.with_terms(ControlledVentilation(gh.air_density, base.VENT_BOX_UPPER))
    truth = vented.defaults(gh)
    truth[vented.index("c_vc")], truth[vented.index("t_vc")] = 5e-3, 24.0
    x["t_in"] = vented.free_run(truth[None], x, gh, 300.0)[0]
    fits = {}
    for wide in (False, True):
        monkeypatch.setattr(base, "WIDE_VENT_BOX", wide)
        got, th, log = base.calibrate_base(m, gh, x, 300.0, 1344, 72, 0, lambda msg: None)
        (vc,) = [e for e in log if e["structure"] == "vent controller"]
        assert vc["kept"], log
        # the lumped coefficients are divided by m_cap: only C_vc / m_cap is identified
        rate = th[got.index("c_vc")] / th[got.index("m_cap")]
        fits[wide] = (rate, got.bounds(gh)[1][got.index("c_vc")], vc, th[got.index("t_vc")])
    assert fits[False][1] == 1e-3 and fits[False][0] > 0.99e-3  # pinned: box and m_cap ≥ 1
    assert fits[True][1] == base.VENT_BOX_UPPER
    assert abs(fits[True][0] - 5e-3) < 0.5e-3 and abs(fits[True][3] - 24.0) < 0.5
    assert fits[True][2]["validation_mse"] < 0.5 * fits[False][2]["validation_mse"]


def test_structure_detail_lists_every_part():
    """The structure log's detail names each part the structure has, the vent controller too."""
    from gateway.diagnose.base import structure_detail
    from gateway.model.vent_control import ControlledVentilation

    gh, _, m = prototype_bases()
    assert structure_detail(m) == "effective heat capacity m_cap"
    vented = m.with_terms(ControlledVentilation(gh.air_density))
    assert structure_detail(vented) == "effective heat capacity m_cap, vent controller (c_vc, t_vc)"
    assert structure_detail(m.with_night_sky()) == (
        "effective heat capacity m_cap, night sky level c_sky_night")


def test_almeria_base_is_scale_free_so_a_heat_source_is_in_its_capacity_scale():
    """Every flux coefficient of the structured Almería base is free and enters its balance
    linearly, as m_cap does the capacity: all of them × λ is the same model, and a heat source
    of λ P then runs exactly as P did. Temperatures cannot tell the scale (the box pins it), so
    a fitted p_heat is in the scale of the fitted capacity m_cap × C_ter: `make demo`'s 9.85
    W m-2 for a simulated 25 into an air node of 2.42 C_ter (README; docs/effects.md, "What a
    flux amplitude's W m-2 are"; the study ``python -m training.demo_heater`` scales this list).
    """
    from training.demo_heater import SCALED as SCALE_FREE

    gh = load_greenhouse("almeria-palmerillas")
    m0 = structure(build_model("almeria", gh), gh, store=False)
    assert set(m0.names) - set(SCALE_FREE) == {"c_tsw", "c_ven_w"}  # inside the square roots
    s = sine_series()
    day = np.arange(len(s)) % 1440 / 1440
    sun = s.columns["i_glob"] > 300.0
    s.columns.update(t_soil=12 + 3 * np.sin(2 * np.pi * (day - 0.4)),
                     vent_roof=np.where(sun, 30.0, 0.0), vent_side=np.where(sun, 20.0, 0.0))
    x = drivers(s, gh)
    e = EFFECTS["heat_source"]
    m = compose(m0, [e], gh, x["_index"][-1])
    th = m.defaults(gh)
    th[m.index("p_heat")], th[m.index("tau_heat_source")] = 25.0, 1500 * 60.0
    run = m.free_run(th[None], x, gh, 60.0)[0]
    scaled = th.copy()
    for name in (*SCALE_FREE, "p_heat"):
        scaled[m.index(name)] *= 2.42
    np.testing.assert_allclose(m.free_run(scaled[None], x, gh, 60.0)[0], run, atol=1e-9)
    scaled[m.index("p_heat")] = 25.0  # the same W m-2 on the scaled base warms the air less
    cooler = m.free_run(scaled[None], x, gh, 60.0)[0]
    np.testing.assert_allclose(cooler[:1501], run[:1501], atol=1e-9)
    assert np.mean(run[1501:] - cooler[1501:]) > 0.3

"""Unit checks of the diagnosis's fitting and evidence tools: τ scans, Levenberg–Marquardt on
multiple shooting, the radiation change, coarsening, residual tools and the humidity evidence
(the structured base: test_diagnose_units.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import residuals as res
from gateway.diagnose.effects import EFFECTS, compose
from gateway.diagnose.fit import (
    Shooting,
    coarsen,
    drivers,
    fit_lm,
    scan_tau,
    window_starts,
)
from gateway.diagnose.radiation import radiation_change
from gateway.diagnose.structure import structure
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.model import psychrometrics as psy
from tests.diagnose_data import prototype_bases, sine_series


def test_scan_recovers_step_time_and_amplitude():
    """Data made by the model itself with a 40 % solar drop at 09:20 (in sunlight, where it is
    identifiable): the τ scan finds it."""
    gh, base, m0 = prototype_bases()
    s = sine_series()
    x = drivers(s, gh)
    e = EFFECTS["solar_gain_change"]
    m = compose(m0, [e], gh, x["_index"][-1])
    th = m.defaults(gh)
    truth = th.copy()
    truth[m.index("d_solar")], truth[m.index("tau_solar_gain_change")] = -0.4, 2000 * 60.0
    x["t_in"] = m.free_run(truth[None], x, gh, 60.0)[0]
    shoot = Shooting(m, x, gh, 60.0, window_starts([(0, len(s))], 180), 180)
    sse0, _ = shoot.sse(th[None])
    sc = scan_tau(shoot, th, e, np.arange(0, len(s), 30, dtype=float) * 60.0, float(sse0[0]))
    assert abs(sc.taus[sc.best] - 2000 * 60.0) <= 30 * 60.0
    assert abs(sc.amps[sc.best] + 0.4) < 0.05


def test_levenberg_marquardt_recovers_base_parameters():
    """From the defaults, LM on multiple shooting recovers the parameters that made the data."""
    gh, base, m = prototype_bases(store=True)
    s = sine_series(n=864, step=300)
    x = drivers(s, gh)
    truth = m.defaults(gh)
    for name, v in (("c_cnv_cnd", 8e-4), ("c_solar", 1.2e-4), ("m_cap", 2.5), ("h_store", 4.0),
                    ("a_store", 0.2)):
        truth[m.index(name)] = v
    x["t_in"] = m.free_run(truth[None], x, gh, 300.0)[0]
    shoot = Shooting(m, x, gh, 300.0, window_starts([(0, 864)], 72, skip=288), 72)
    free = [m.index(n) for n in ("c_cnv_cnd", "c_solar", "m_cap")]
    start = truth.copy()
    start[free] = m.defaults(gh)[free]
    lo, hi = m.bounds(gh)
    got = fit_lm(shoot, start, free, lo, hi, 40)
    np.testing.assert_allclose(got[free], truth[free], rtol=0.02)
    assert shoot.mse(got[None])[0] < 1e-6


def test_radiation_change_from_inside_radiation():
    gh = load_greenhouse("almeria-palmerillas")
    m = structure(build_model("almeria", gh), gh, store=False)
    s = sine_series()
    x = drivers(s, gh)
    th = m.defaults(gh)
    c = th[m.index("c_tsw")]
    x["i_in"] = c * x["i_glob"] * np.where(np.arange(2880) >= 1900, 0.6, 1.0)
    tau, d = radiation_change(m, x, th, [(0, 2880)], 0.0)
    # 1900 falls in the night: any start between the last sunlit sample before it and the first
    # after is equally good, the latest is chosen
    first_sun = 1900 + int(np.argmax(x["i_glob"][1900:] > 5.0))
    assert tau == first_sun * 60.0
    assert abs(d + 0.4) < 1e-9


def test_coarsen_keeps_state_samples_and_averages_inputs():
    s = sine_series(n=600)
    c = coarsen(s, 5)
    assert len(c) == 120 and c.step == 300.0
    np.testing.assert_array_equal(c.columns["t_in"], s.columns["t_in"][::5])
    np.testing.assert_allclose(c.columns["i_glob"], s.columns["i_glob"].reshape(-1, 5).mean(axis=1))


def test_change_point_and_hour_profile():
    rng = np.random.default_rng(0)
    v = np.concatenate([rng.normal(0, 1, 50), rng.normal(3, 1, 30)])
    k, t = res.change_point(v)
    assert 47 <= k <= 53 and t > 8
    time = np.datetime64("2020-01-01T00:00") + np.arange(2880).astype("timedelta64[m]")
    r = np.where((np.arange(2880) // 60) % 24 == 13, 1.0, 0.0)
    prof = res.hour_profile(time, r)
    assert prof[13] == 1.0 and np.nansum(prof) == 1.0
    acf = res.autocorrelation(np.sin(np.arange(2880) * 2 * np.pi / 1440), np.array([0, 720, 1440]))
    assert acf[0] == 1.0 and acf[1] < -0.4 and acf[2] > 0.4


def _humid(f_after: float, rh_in: bool = True, seed: int = 0) -> dict:
    """Four days at 5 min obeying the night vapour balance e_in − e_out = f D (+ noise), the
    exchange fraction f stepping from 0.4 to ``f_after`` at day 2; sun from 06 to 18 h."""
    from gateway.diagnose.structure import INDEX

    rng = np.random.default_rng(seed)
    t = np.arange(4 * 288) * 300.0
    hour = (t % 86400) / 3600
    t_out = 12 + 6 * np.sin(2 * np.pi * (hour - 9) / 24) + rng.normal(0, 1.0, len(t)).cumsum() * 0.05
    t_in = t_out + 1.0
    e_out = psy.vapour_pressure(t_out, 55 + 10 * np.sin(t / 86400.0))
    f = np.where(t >= 2 * 86400, f_after, 0.4)
    e_in = e_out + f * (psy.saturation_vapour_pressure(t_in) - e_out) + rng.normal(0, 0.01, len(t))
    x = {INDEX: t, "t_in": t_in, "t_out": t_out, "rh_out": psy.relative_humidity(t_out, e_out),
         "i_glob": np.where((hour > 6) & (hour < 18), 300.0, 0.0), "wind": rng.uniform(0, 3, len(t))}
    if rh_in:
        x["rh_in"] = psy.relative_humidity(t_in, e_in)
    return x


def test_humidity_evidence_sees_more_air_exchange_only():
    from gateway.diagnose.humidity import exchange_step_bic

    seg = [(0, 4 * 288)]
    dbic, c = exchange_step_bic(_humid(0.25), seg, 2 * 86400.0)
    assert dbic < -20 and c == pytest.approx(-0.15, abs=0.03)
    # no change of the exchange: only the extra parameter's penalty, ln(night hours)
    dbic0, _ = exchange_step_bic(_humid(0.4), seg, 2 * 86400.0)
    assert 0 < dbic0 < 6
    # less exchange (a rise of f) is no evidence for more exchange
    assert exchange_step_bic(_humid(0.55), seg, 2 * 86400.0)[0] > 0
    # graceful fallback: no inside RH, or τ with too few night hours after it → no evidence
    assert exchange_step_bic(_humid(0.25, rh_in=False), seg, 2 * 86400.0)[0] == 0.0
    assert exchange_step_bic(_humid(0.25), seg, 3.9 * 86400.0)[0] == 0.0


def test_signature_of_a_short_held_out_part_says_no_nan():
    an = {"mean": 0.1, "mae": 0.3, "correlations": {"radiation": 0.5}, "hour_profile": np.full(24, np.nan),
          "acf_1h": 0.7, "acf_1d": np.nan, "change_points": {}}
    text = res.describe(an, np.array(["2020-01-01T00:00"], dtype="datetime64[s]"), 0)
    assert "nan" not in text and "autocorrelation 0.70 at 1 h" in text


def test_drift_start_is_found_when_the_base_is_right():
    """8 days made by the structured prototype itself with a 0.5 K d-1 drift from day 3.4: the
    search (scan, joint refit, rescan) puts the start within 3 h of the truth. The suite's
    drift starts 1–2 days off come from the base's day-scale error, not from the search
    (docs/effects.md, "Start times and the judge's power"; tests/generality/tau_profile.py)."""
    from tests.generality.tau_profile import synthetic_drift_start

    assert abs(synthetic_drift_start(0.0)) <= 3.0


def test_drift_start_does_not_depend_on_the_calibration_part():
    """The same model-made ramp starting well inside the calibration part (day 1.4 of 8, C ends at
    day 4) or wholly inside the held-out half (day 5.4) is placed within 3 h: the base calibrated
    on data holding the ramp's start, its refit and the τ grid do not misplace a drift. The
    suite's 1.5–3 day errors are reproduced by the same ramp added to effect-free windows and
    track the base's own day-scale error there (docs/effects.md, "The drift's start (issue 10,
    third look)")."""
    from tests.generality.tau_profile import synthetic_drift_start

    for day in (1.4, 5.4):
        assert abs(synthetic_drift_start(0.0, start_day=day)) <= 3.0


def test_a_base_error_after_the_start_moves_the_drift_start_its_way():
    """The mechanism behind the suite's drift starts, on model-made data: a 0.6 K, 2-day bump of
    base error 1.6 d after the start (the size of the prototype's error on days 7–9 of the dev
    windows) moves the least-squares start by more than the suite's 12 h, later when the base
    is too warm there (the reading lowered), earlier when it is too cold. A change that claims
    to fix the drift's start must move these, not only the suite's cases."""
    from tests.generality.tau_profile import synthetic_drift_start

    assert synthetic_drift_start(0.6) > 12.0
    assert synthetic_drift_start(-0.6) < -12.0


def test_humidity_dates_more_air_exchange_that_the_temperature_leaves_open():
    """Extra air exchange from midnight inside 36 h of still, overcast weather: the air sits at
    the outside temperature, so the temperature cannot tell when the exchange rose (its τ
    profile is flat until the weather moves again, 24 h later); the night vapour balance
    (humidity.py) steps at the change. The scan takes the second output's ΔBIC into its profile
    and puts the start within 3 h of the truth, also when it takes the latest of the equally
    good starts (the fold fits); before, that was the end of the still spell (+24 h)."""
    from gateway.diagnose.effect_fit import scan

    gh, _, m0 = prototype_bases()
    n, dt = 5 * 288, 300.0
    s = sine_series(n=n, step=300)
    t = np.arange(n) * dt
    still = (t >= 1.5 * 86400) & (t < 3.0 * 86400)
    s.columns["t_out"] = np.where(still, 10.0, s.columns["t_out"])
    s.columns["i_glob"] = np.where(still, 0.0, s.columns["i_glob"])
    e = EFFECTS["extra_ventilation"]
    x = drivers(s, gh)
    m = compose(m0, [e], gh, float(x["_index"][-1]))
    truth = m.defaults(gh)
    truth[m.index("c_thermal")] = 0.0  # no sky loss: the still air relaxes to T_out
    base = truth.copy()
    tau = 2.0 * 86400
    truth[m.index(e.amp_name)], truth[m.index(e.tau_name)] = 3.0, tau
    t_in = m.free_run(truth[None], x, gh, dt)[0]
    rng = np.random.default_rng(0)
    e_out = psy.vapour_pressure(x["t_out"], x["rh_out"])
    f = np.where(t >= tau, 0.25, 0.4)  # night exchange fraction of humidity.py (1)
    e_in = e_out + f * (psy.saturation_vapour_pressure(t_in) - e_out) + rng.normal(0, 0.01, n)
    s.columns["t_in"] = t_in + rng.normal(0, 0.05, n)
    s.columns["rh_in"] = psy.relative_humidity(t_in, e_in)
    x = drivers(s, gh)
    shoot = Shooting(m, x, gh, dt, window_starts([(0, n)], 72, skip=72), 72)
    for latest in (False, True):
        sc = scan(shoot, base, e, 4.0 * 86400, [(0, n)], latest=latest)
        assert abs(sc.taus[sc.best] - tau) <= 3 * 3600.0, (latest, sc.taus[sc.best] / 3600)
        assert sc.amps[sc.best] == pytest.approx(3.0, rel=0.1)


def test_fit_effect_at_holds_the_start_and_fits_the_amplitude():
    """``effect_fit.fit_effect_at`` (the headroom study's oracle): on 5 days made by the structured
    prototype with a 0.5 K d-1 drift from day 2.4, the effect fitted with its start held at the
    truth keeps that start exactly and recovers the rate, and fits better (lower ΔBIC) than held
    a day late."""
    from gateway.diagnose.effect_fit import Context, fit_effect_at

    gh, _, m0 = prototype_bases()
    n, dt = 5 * 288, 300.0
    x = drivers(sine_series(n=n, step=300), gh)
    e = EFFECTS["sensor_drift"]
    m = compose(m0, [e], gh, float(x["_index"][-1]))
    tau = 2.4 * 86400.0
    truth = m.defaults(gh)
    truth[m.index(e.amp_name)], truth[m.index(e.tau_name)] = 0.5, tau
    x["t_in"] = m.free_run(truth[None], x, gh, dt)[0] + np.random.default_rng(0).normal(0, 0.05, n)
    ctx = Context(x, gh, dt, float(x["_index"][-1]), 72, n // 2)
    right = fit_effect_at(ctx, m, m0, m0.defaults(gh), e, [(0, n)], tau)
    late = fit_effect_at(ctx, m, m0, m0.defaults(gh), e, [(0, n)], tau + 86400.0)
    assert right.theta[m.index(e.tau_name)] == tau
    assert late.theta[m.index(e.tau_name)] == tau + 86400.0
    assert right.theta[m.index(e.amp_name)] == pytest.approx(0.5, rel=0.1)
    assert right.delta_bic < late.delta_bic < 0

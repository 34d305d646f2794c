"""The night vapour balance as a second output of ``sensor_drift`` (humidity.DriftEvidence,
docs/effects.md "The drift's start on the humidity"): on data that obey the balance with the
true air temperature, a drift added to the temperature reading alone (RH untouched, as the
kit's RH refers to the true air) is undone best at its true start and rate."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import humidity
from gateway.diagnose.structure import INDEX
from gateway.model import psychrometrics as psy

DAY = 86400.0
START, RATE, DAYS = 3.4 * DAY, 0.5, 8


def _drifted(rh_in: bool = True, seed: int = 1) -> dict:
    """``DAYS`` days at 5 min: e_in − e_out = f D (f = 0.4 + 0.05 u_wind, + noise) at the true
    air temperature; the inside reading drifts ``RATE`` K d-1 from ``START``; sun 06–18 h."""
    rng = np.random.default_rng(seed)
    t = np.arange(DAYS * 288) * 300.0
    hour = (t % DAY) / 3600
    daily = rng.normal(0, 3, DAYS + 1)[(t // DAY).astype(int)]
    t_out = 8 + daily + 6 * np.sin(2 * np.pi * (hour - 9) / 24)
    t_air = t_out + 2.0
    wind = rng.uniform(0.5, 4.0, DAYS + 1)[(t // DAY).astype(int)]
    e_out = psy.vapour_pressure(t_out, 70 + 10 * np.sin(t / DAY))
    f = 0.4 + 0.05 * wind
    e_in = e_out + f * (psy.saturation_vapour_pressure(t_air) - e_out) + rng.normal(0, 0.005, len(t))
    x = {INDEX: t, "t_in": t_air + RATE * np.maximum(t - START, 0.0) / DAY, "t_out": t_out,
         "rh_out": psy.relative_humidity(t_out, e_out), "wind": wind,
         "i_glob": np.where((hour > 6) & (hour < 18), 300.0, 0.0)}
    if rh_in:
        x["rh_in"] = psy.relative_humidity(t_air, e_in)
    return x


def test_drift_is_dated_by_the_night_vapour_balance():
    x, seg = _drifted(), [(0, DAYS * 288)]
    taus = np.arange(1.0, 6.5, 0.125) * DAY
    # the rate as a temperature fit couples it: the offset at the end of the data held
    end = DAYS * DAY
    amps = RATE * (end - START) / (end - taus)
    prof = humidity.drift_profile(x, seg, taus, amps)
    assert abs(taus[np.argmin(prof)] - START) <= 6 * 3600.0
    assert prof.min() < -10.0
    # at the true start, the wrong sign makes the balance worse: evidence against
    assert humidity.drift_profile(x, seg, np.array([START]), np.array([-RATE]))[0] > 0.0
    # no drift in the reading: a correction only makes the balance worse
    x0 = dict(x, t_in=x["t_in"] - RATE * np.maximum(x[INDEX] - START, 0.0) / DAY)
    assert np.all(humidity.drift_profile(x0, seg, taus, amps) >= 0.0)


def test_drift_evidence_is_silent_without_humidity_or_switched_off(monkeypatch: pytest.MonkeyPatch):
    seg, taus, amps = [(0, DAYS * 288)], np.array([START, 2 * DAY]), np.array([RATE, RATE])
    ev = humidity.DriftEvidence()
    monkeypatch.setattr(humidity, "DRIFT_EVIDENCE", True)
    assert np.all(ev.profile(None, _drifted(rh_in=False), None, seg, taus, amps) == 0.0)
    # τ with fewer than MIN_HOURS night hours after it, τ = 0, or no rate: silent
    edge = np.array([DAYS * DAY - 3600.0, 0.0, START])
    assert np.all(ev.profile(None, _drifted(), None, seg, edge, np.array([RATE, RATE, 0.0])) == 0.0)
    assert ev.delta_bic(None, _drifted(), None, seg, START, RATE) < 0.0
    monkeypatch.setattr(humidity, "DRIFT_EVIDENCE", False)
    assert np.all(ev.profile(None, _drifted(), None, seg, taus, amps) == 0.0)

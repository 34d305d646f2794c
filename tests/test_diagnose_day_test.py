"""Diagnosis (issue 4) with the judge as shipped (``judge.DAY_TEST``) on the reference
simulator's data: the day test on 10-day records with the change at day 5.6, and effects that
start inside the calibration part (day 1.5 of 6). Cases, sizes and equivalences in
tests/diagnose_cases.py; the 10-day cases of a plant share one base calibration
(``shared_calibration``: their changes start after it)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import diagnose, to_json
from gateway.diagnose import judge as jd
from tests import diagnose_cases as cases
from tests.diagnose_cases import (
    EQUIVALENT,
    LONG_AT,
    LONG_DAYS,
    shared_calibration_in_module,  # noqa: F401 (fixture)
)


@pytest.mark.slow
@pytest.mark.parametrize(("plant", "effect"), [
    ("almeria", "heater"), ("prototype", "heater"), ("almeria", "cover_transmission"),
    ("prototype", "cover_transmission")])
def test_day_test_names_the_effect_on_ten_days(tmp_path, plant, effect):
    """The judge as shipped (``judge.DAY_TEST``) on 10-day records, the change at day 5.6: the
    first finding names it, significant over the held-out days after its start, its start
    within 3 h (measured on all 12 cases: right first in 9 of 12, the heaters at day p 0.003
    and 0.010, the whitewash 0.003 and 0.008; docs/effects.md, "What switching it on costs on
    short records")."""
    assert jd.DAY_TEST
    truth = {}
    series, gh, model, t0 = cases.data(tmp_path, plant, effect, at=LONG_AT, days=LONG_DAYS,
                                       post=lambda r: truth.update(r.series))
    d = diagnose(series, gh, model)
    assert d.findings, f"nothing found; rejected: {d.rejected}"
    first = d.findings[0]
    assert first.effect.name in EQUIVALENT[effect]
    if effect == "heater":
        # what the temperatures fix is the warming rate P / C, not P (the base is scale-free):
        # within 35 % of the simulator's 25 W m-2 into its air + fast-mass node (measured:
        # +25 % almeria, -24 % prototype, where P itself is +18 % and -60 %)
        rate = 25.0 * 3600.0 / float(np.nanmedian(truth["cap_air"]))
        assert abs(first.heating_rate / rate - 1.0) <= 0.35, (first.heating_rate, rate)
        assert to_json(d)["findings"][0]["heating_rate_K_per_h"] == first.heating_rate
    kept = next(t for t in d.trials if t["effect"] == first.effect.name and t["ok"])
    assert kept["p"] == kept["p_days"] <= jd.ALPHA and len(kept["day_means"]) >= 4, kept
    assert cases.first_gain(d) >= 0.30
    assert cases.start_lag_h(first.start, t0) <= 3.0


@pytest.mark.slow
@pytest.mark.parametrize(("plant", "effect"), [
    pytest.param("almeria", "cover_transmission", marks=pytest.mark.xfail(
        reason="the base chosen on the inner validation split (days 2-3 all whitened) carries "
               "the change: held-out MAE 0.225 K without it, the clean-data level; docs/effects.md",
        strict=False)),
    ("prototype", "sensor_radiation_bias")])
def test_effect_starting_in_the_calibration_part(tmp_path, plant, effect):
    """An effect from day 1.5 contaminates the base calibration (first 3 days); the joint refit
    with the effect still names it, with its start, and cuts the held-out error."""
    series, gh, model, t0 = cases.data(tmp_path, plant, effect, at=1.5)
    d = diagnose(series, gh, model)
    assert d.findings and d.findings[0].effect.name in EQUIVALENT[effect], d.rejected
    assert cases.first_gain(d) >= 0.30
    assert cases.start_lag_h(d.findings[0].start, t0) <= 3.0

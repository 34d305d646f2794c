"""tests/generality/base_carry.py's helpers on made-up arrays (the study itself runs a suite
case: docs/effects.md, "Why the freer base gives twonode winter a heater")."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import judge
from tests.generality.base_carry import apply_settings, at_bounds, per_day, split_stats


def test_parameters_on_a_bound_are_named_with_the_bound():
    lo, hi = np.array([0.0, 5e3, 1.0]), np.array([2e-3, 4e5, 12.0])
    edge = at_bounds(["c_loss", "c_store", "m_cap"], np.array([0.0, 4e5, 2.7]), lo, hi)
    assert edge == {"c_loss": "lower", "c_store": "upper"}


def test_night_and_day_statistics_skip_missing_rows():
    r = np.array([1.0, -1.0, np.nan, 0.5, 0.5])
    night = np.array([True, True, True, False, False])
    st = split_stats(r, night)
    assert st["night"] == pytest.approx((0.0, 1.0)) and st["day"] == pytest.approx((0.5, 0.5))


def test_days_count_from_the_first_row():
    dt = 6 * 3600.0  # four rows a day
    r = np.array([1.0, 1.0, 3.0, 3.0, 3.0, 3.0])
    assert per_day(r, 2, dt) == {0: 1.0, 1: 3.0}  # rows 2..7: day 0 holds rows 2 and 3


def test_settings_set_a_switch_and_refuse_an_unknown_name(monkeypatch):
    monkeypatch.setattr(judge, "REFERENCE_TEST", False)
    apply_settings(["judge.REFERENCE_TEST=True"])
    assert judge.REFERENCE_TEST is True
    monkeypatch.setattr(judge, "REFERENCE_TEST", False)  # undone by monkeypatch as well
    with pytest.raises(SystemExit):
        apply_settings(["judge.NO_SUCH_SWITCH=1"])

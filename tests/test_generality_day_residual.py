"""tests/generality/day_residual.py: the daily means, features and leave-one-window-out R²
on synthetic data (no generator runs)."""

from __future__ import annotations

import numpy as np

from tests.generality.day_residual import column, daily_features, daily_means, lowo_r2

DT = 3600.0  # [s] a row an hour: 24 rows a day


def test_lowo_r2_finds_a_shared_line_and_not_noise() -> None:
    rng = np.random.default_rng(0)
    groups = np.repeat(np.arange(8), 7)
    f = rng.normal(size=(len(groups), 1))
    y = 0.5 + 2.0 * f[:, 0] + 0.05 * rng.normal(size=len(groups))
    assert lowo_r2(y, f, groups) > 0.95
    unrelated = rng.normal(size=(len(groups), 1))
    assert lowo_r2(y, unrelated, groups) < 0.1


def test_lowo_r2_drops_nan_rows_and_needs_two_groups() -> None:
    groups = np.repeat(np.arange(4), 5)
    f = np.arange(20.0)[:, None]
    y = 3.0 * f[:, 0]
    y_nan = y.copy()
    y_nan[3] = np.nan
    assert np.isclose(lowo_r2(y_nan, f, groups), lowo_r2(np.delete(y, 3), np.delete(f, 3, 0),
                                                         np.delete(groups, 3)))
    assert np.isnan(lowo_r2(y, f, np.zeros(20, int)))


def test_daily_means_start_at_the_given_row() -> None:
    level = np.array([1.0, -2.0, 4.0])
    r = np.repeat(level, 24)[24:]  # the first day is not in r
    r[5] = np.nan
    got = daily_means(r, 24, DT, 3)
    assert np.isnan(got[0]) and np.allclose(got[1:], level[1:])


def test_daily_features_change_and_previous_days() -> None:
    t_day = np.array([10.0, 12.0, 9.0, 15.0])
    rad_day = np.array([100.0, 0.0, 50.0, 20.0])
    n = 24 * len(t_day)
    x = {"t_out": np.repeat(t_day, 24), "i_glob": np.repeat(rad_day, 24),
         "wind": np.ones(n), "rh_out": np.full(n, 80.0), "t_in": np.full(n, 18.0),
         "rh_in": np.full(n, 70.0), "cloud": np.full(n, 0.25)}
    f = daily_features(x, np.full(n, 200.0), DT)
    assert np.allclose(f["dt_out"][1:], np.diff(t_day)) and f["dt_out"][0] == 0.0
    assert np.allclose(f["rad_prev"][1:], rad_day[:-1])
    assert np.isclose(f["rad_prev3"][3], rad_day[:3].mean())
    assert np.allclose(f["kt"], rad_day / 200.0)
    # night rows exist only on day 1 (no radiation): its clearness is 1 - cloud
    assert np.isclose(f["night_clear"][1], 0.75) and np.isnan(f["night_clear"][0])


def test_shift_is_relative_to_the_calibration_days() -> None:
    rec = {"split_day": 2.0, "features": {"t_out": [10.0, 12.0, 20.0, 5.0]}}
    got = column(rec, "t_out_shift")
    assert np.allclose(got, np.array([10.0, 12.0, 20.0, 5.0]) - 11.0)
    assert np.allclose(column(rec, "t_out"), rec["features"]["t_out"])

"""The day test on short records (1.5-4 days, docs/effects.md "Known limits"): the first and last
days are partial, so some ±2 h windows of a day's half-hour profile, and some days' state bins,
hold no value at all. Those come out NaN, as before, and say nothing on stderr (numpy's
"All-NaN slice encountered" RuntimeWarning was printed by every diagnose of such a record)."""

from __future__ import annotations

import warnings

import numpy as np

from gateway.diagnose import day_test as dtm

DT = 600
DAY = 86400 // DT


def _record(days: float, start: str = "2026-06-01T12:00"):
    """``days`` of 10-min residuals starting at ``start`` (so the first day is partial), with a
    sunny day's drivers for the controller state."""
    rng = np.random.default_rng(1)
    n = int(days * DAY)
    t = np.datetime64(start) + np.arange(n) * np.timedelta64(DT, "s")
    sec = t.astype("datetime64[s]").astype(np.int64) % 86400
    bell = np.clip(np.sin(np.pi * (sec - 6 * 3600) / (12 * 3600)), 0.0, None)
    r = rng.normal(0.0, 0.3, n)
    x = {"t_in": 20.0 + 3.0 * bell + r, "t_out": 15.0 + 5.0 * bell, "i_glob": 800.0 * bell}
    return t, r, x


def _median_by_loop(a: np.ndarray) -> np.ndarray:
    """Median of the finite values along the last axis, NaN where there is none."""
    flat = a.reshape(-1, a.shape[-1])
    out = [np.median(row[np.isfinite(row)]) if np.isfinite(row).any() else np.nan for row in flat]
    return np.array(out).reshape(a.shape[:-1])


def test_a_partial_day_gives_nan_windows_without_a_warning() -> None:
    t, r, _ = _record(1.5)
    sec = t.astype("datetime64[s]").astype(np.int64)
    _, day = np.unique(sec // 86400, return_inverse=True)
    nb = int(86400 // dtm.BIN_S)
    m = dtm._cells(day, (sec % 86400) // int(dtm.BIN_S), r, nb)
    assert np.isnan(m[0, :20]).all()  # the first day starts at 12:00
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = dtm.sharp_part(m)
    w = int(round(2 * 3600 / dtm.BIN_S))
    idx = (np.arange(nb)[:, None] + np.arange(-w, w + 1)[None, :]) % nb
    np.testing.assert_array_equal(got, m - _median_by_loop(m[..., idx]))
    assert np.isnan(got[0, :20]).all() and np.isfinite(got[0, 24:]).all()


def test_a_day_without_state_bins_gives_nan_without_a_warning() -> None:
    t, r, x = _record(2.0)
    sec = t.astype("datetime64[s]").astype(np.int64)
    _, day = np.unique(sec // 86400, return_inverse=True)
    v = x["i_glob"].copy()
    v[day == 1] = np.nan  # a day without radiation readings: no state bin at all
    edges = np.array([0.0, 100.0, 400.0, 800.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = dtm._state_units(day, v, edges, r, min_n=3)
    m = dtm._cells(day, np.where(np.isfinite(v), np.clip(np.searchsorted(edges, v, "right") - 1,
                                                           0, 2), -1), r, 3, 3)
    np.testing.assert_array_equal(got, m - _median_by_loop(m)[:, None])
    assert np.isnan(got[1]).all() and np.isfinite(got[0]).any()


def test_day_test_on_a_short_record_says_nothing_on_stderr(monkeypatch) -> None:
    """What diagnose calls on a 1.5-4 day record: no RuntimeWarning, and the result numpy's
    plain ``nanmedian`` (the code before, its warning silenced) gives."""
    def quiet(a: np.ndarray) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(a, axis=-1)

    for days in (1.5, 3.0, 4.0):
        t, r, x = _record(days)
        a = len(t) // 2
        args = (t[a:], r[a:], t[:a], r[:a])
        kw = {"state_h": dtm.controller_state(x, a, r[a:]), "state_c": dtm.controller_state(x, 0, r[:a])}
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            d = dtm.day_test(*args, **kw)
        with monkeypatch.context() as m:
            m.setattr(dtm, "nan_median", quiet)
            before = dtm.day_test(*args, **kw)
        assert d == before, days
        assert d.n_held >= 2 or days < 2.0  # the record is long enough for the test to run

"""Every forecast replay reports is causal: rows after a forecast's start do not change it.

A forecast "with the weather later measured" may read the later weather (that is its
definition, docs/online-estimator.md), but nothing else after its start: not the later inside
readings (the leak fixed on 2026-11-29), not the estimator's later parameters, not a later
error of the correction or the combination. The outlook forecasts (what the live gateway can
do) read nothing after their start at all. Checked here whole, on replay's own output, not
part by part: the same series with its future changed gives the same forecasts up to the cut.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_forecaster import QuickCorrector
from test_online import ALMERIA, GH, model_data

from gateway.estimate import correction
from gateway.estimate.horizon import INSIDE_READINGS
from gateway.estimate.online import online_settings
from gateway.estimate.replay import replay

HORIZONS = (15, 60)
BUDGET = {"t_in": {"iterations": 3, "bats": 10, "every": 15},
          "i_in": {"iterations": 3, "bats": 10}}
CUT = 14 * 60
"""The last row both series share [1-minute rows]: 14 h, after the morning's sun. A multiple of
the air's search period in BUDGET (every 15th sample, as tests/vsensor_data.py TINY) and of the
radiation's (every 20th): both searches run at the cut itself, where a read of any later row
would change θ[CUT] (every sample searched, the three replays took ~3x the CPU)."""
WEATHER = ("t_out", "rh_out", "i_glob", "wind", "vent_roof", "vent_side", "lai")
"""What a measured-weather forecast may read after its start (the rest is held at it)."""


def changed_after(series, cut: int, columns, seed: int):
    """``series`` with ``columns`` scaled by random factors after row ``cut`` and a gap in t_in."""
    other = series.slice(0, len(series))
    rng = np.random.default_rng(seed)
    for name in columns:
        v = other.columns[name]
        v[cut + 1 :] = v[cut + 1 :] * rng.uniform(0.7, 1.3, len(v) - cut - 1)
    if "t_in" in columns:
        other.columns["t_in"][cut + 20 : cut + 26] = np.nan
    return other


@pytest.fixture(scope="module")
def pair(request):
    mp = pytest.MonkeyPatch()
    mp.setattr(correction, "Corrector", QuickCorrector)
    request.addfinalizer(mp.undo)
    series = model_data(ALMERIA, GH, hours=20, seed=4, start_hour=4.0)
    settings = online_settings(ALMERIA, GH, BUDGET)
    inside = [c for c in series.columns if c not in WEATHER]
    runs = {}
    for label, columns in (("all", list(series.columns)), ("inside", inside)):
        other = changed_after(series, CUT, columns, seed=9)
        runs[label] = replay(ALMERIA, other, GH, settings=settings, horizons=HORIZONS)
    runs["base"] = replay(ALMERIA, series, GH, settings=settings, horizons=HORIZONS)
    return runs


def kinds(f: dict) -> list[str]:
    return [k for k in f if k not in ("target", "measured", "persistence")]


def by_start(f: dict, name: str, h: int, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    out[f["target"] - h] = f[name]
    return out


def test_the_loop_itself_is_causal(pair):
    base, other = pair["base"], pair["all"]
    assert all(CUT % g.every == 0 for g in base.settings)  # every search runs at the cut
    np.testing.assert_array_equal(base.theta[: CUT + 1], other.theta[: CUT + 1])
    assert not np.array_equal(base.theta[CUT + 30 :], other.theta[CUT + 30 :], equal_nan=True)


@pytest.mark.parametrize("h", HORIZONS)
def test_outlook_forecasts_read_nothing_after_their_start(pair, h):
    """The future changed everywhere: every forecast made with the outlook (and the ARX's
    outlook row) is bit-identical at every start up to the cut, and differs after it."""
    base, other = pair["base"], pair["all"]
    n, f, g = len(base.measured), base.horizons[h], other.horizons[h]
    names = [k for k in kinds(f) if k.endswith("_outlook")]
    assert {"adaptive_outlook", "arx_outlook", "combined_outlook", "corrected_outlook"} <= set(names)
    for name in names:
        a, b = by_start(f, name, h, n), by_start(g, name, h, n)
        assert np.isfinite(a[: CUT + 1]).sum() > 500, name
        np.testing.assert_array_equal(a[: CUT + 1], b[: CUT + 1], err_msg=name)
        assert not np.array_equal(a[CUT + 1 :], b[CUT + 1 :], equal_nan=True), name


@pytest.mark.parametrize("h", HORIZONS)
def test_measured_weather_forecasts_read_only_the_later_weather(pair, h):
    """Only the inside readings changed after the cut (the weather kept): every forecast made
    with the measured weather at a start up to the cut is bit-identical, though its horizon
    reaches into the changed rows (a forecast that read a later inside reading would move)."""
    base, other = pair["base"], pair["inside"]
    assert set(INSIDE_READINGS) & set(ALMERIA.requires) - {"t_in"}  # the model reads one
    n, f, g = len(base.measured), base.horizons[h], other.horizons[h]
    names = [k for k in kinds(f) if not k.endswith("_outlook")]
    assert {"adaptive", "adaptive_kf", "arx", "combined", "corrected"} <= set(names)
    reach = slice(CUT + 1 - h, CUT + 1)  # starts whose horizon crosses the cut
    for name in names:
        a, b = by_start(f, name, h, n), by_start(g, name, h, n)
        assert np.isfinite(a[reach]).all(), name
        np.testing.assert_array_equal(a[: CUT + 1], b[: CUT + 1], err_msg=name)


def test_a_forecast_that_read_later_inside_readings_would_be_caught(pair):
    """The check above has teeth: the almeria model's free run over the same starts with the
    inside readings as later measured (the leak) differs between the two series."""
    base, other = pair["base"], pair["inside"]
    h, starts = 15, np.arange(CUT + 1 - 15, CUT + 1)
    theta = base.theta[starts]
    leaky = [ALMERIA.forecast(theta, r.x, GH, r.dt, starts, h) for r in (base, other)]
    assert not np.array_equal(*leaky)

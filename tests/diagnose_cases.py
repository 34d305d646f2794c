"""The model-made diagnosis cases of tests/test_diagnose*.py: the reference simulator's records
with one undeclared effect (sizes, equivalences, tolerances) and a base calibration shared by
the cases whose calibration part is the same.

Every case of a plant is simulated with seed 2 on the same weather, so the rows before the
effect's start are the clean record's, bit for bit: with the change after the calibration part
(day 3.6 of 6, day 5.6 of 10) the structural calibration (``base.calibrate_base``, a fifth to a
third of a case's time) sees the same data in every case. ``shared_calibration`` computes it
once per worker for each distinct input and hands each case a fresh copy of the result.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import os
import pickle
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from gateway.diagnose import base as base_module
from gateway.diagnose import judge, search, to_json
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.series import load_series
from training.simulate import simulate
from training.simulate.weather import DEFAULT_START, load_weather, parse_start

STEP = 300.0
DAYS = 6
LONG_DAYS, LONG_AT = 10, 5.6
"""The day test's records: 10 days, the change at day 5.6 (4.4 held-out days after it)."""
PRESET = {"almeria": "almeria-palmerillas", "prototype": "biskra-prototype"}
EQUIVALENT = {
    "cover_transmission": {"solar_gain_change"},
    "extra_leakage": {"extra_ventilation"},
    "heater": {"heat_source", "night_heat_source"},
    "thermal_mass": {"thermal_mass", "heat_store_added"},
    "sensor_radiation_bias": {"sensor_radiation_bias"},
    "sensor_drift": {"sensor_drift"},
}
"""Simulator effect → library effect(s) that count as naming it (docs/effects.md)."""
SPECS = {
    "cover_transmission": {"almeria": "factor=0.5", "prototype": "factor=0.5"},
    "extra_leakage": {"almeria": "ach=4", "prototype": "ach=30"},
    "heater": {"almeria": "power=25", "prototype": "power=25"},
    "thermal_mass": {"almeria": "factor=3", "prototype": "factor=10"},
    "sensor_radiation_bias": {"almeria": "k=0.006", "prototype": "k=0.006"},
    "sensor_drift": {"almeria": "rate=0.5", "prototype": "rate=0.5"},
}
"""Effect sizes a grower would care about (docs/effects.md, "Effect sizes in the tests"):
whitewash halving the transmission; both doors of the 877 m2 house open (4 air changes per
hour) or the 0.76 m3 box's door ajar (30 h-1, about 6 L/s); a 25 W m-2 heater (22 kW for the
Almería house, 17 W for the box); water barrels tripling the Almería air+fast-mass capacity
(+20 kJ m-2 K-1, 5 L of water per m2) or 6 L of water jugs in the box (x 10); an unshielded
sensor (+3 to +5 K at noon); a sensor drifting 0.5 K per day."""
KNOWN_MISSES: set[tuple[str, str]] = {("almeria", "sensor_drift")}
"""Cases the diagnosis does not yet get right on this data: kept as expected failures so that
the suite shows them, not hides them (docs/effects.md, "Known limits").

sensor_drift/almeria: with 3 held-out days the drift's cut (29 %) is not significant (one-
sided p = 0.08 over the 8 pieces after its start: a ramp from zero gives few pieces of gain);
the issue-10 judge asks p ≤ 0.05 (docs/effects.md, "How the diagnosis decides"). Before it,
extra_leakage/prototype was one until the base could take the night-time deficit as a long-
wave loss to the sky instead of a constant sensor offset (docs/effects.md, "Base structure")."""
START_TOLERANCE_H = {"sensor_drift": 18.0, "thermal_mass": 6.0}
"""How far the estimated start may be from the truth [h]: 3 h for a step; a ramp starts from
zero and only rises above the 0.1 K resolution hours later (0.5 K/d: 5 h), so its start is
less sharp; a capacity change shows only while the temperature swings (the reported start is
the best-fitting one, 3.2 h early on Almería)."""


@functools.cache
def clean(plant: str, days: int):
    """The clean record: one simulation per plant and length per worker, which the effect-free
    cases take (a copy each: ``post`` may change it)."""
    return simulate(plant=plant, weather="almeria", days=days, seed=2, step=60)


@functools.cache
def first_time(days: int) -> np.datetime64:
    """The records' first time: the first row of the synthetic Almería weather ``simulate``
    runs on (its default start; the plant does not enter), without simulating a clean record
    only to read it (``data`` checks it against the clean record wherever one is made)."""
    t0 = parse_start(DEFAULT_START.get("almeria", "2009-11-01"))
    return load_weather("almeria", t0, days, 60.0, 2).time[0]


def data(tmp_path, plant: str, effect: str | None, post=None, at: float = 3.6,
         days: int = DAYS):
    """(series at ``STEP``, greenhouse, model, effect start) of the ``days``-day record of
    ``plant`` with ``effect`` (``SPECS``) from day ``at``, or clean (None); ``post`` changes
    the record before it is written to ``tmp_path``."""
    t0 = str(first_time(days) + np.timedelta64(int(at * 86400), "s"))
    if effect is None:  # the clean record, simulated once (the same call without effects)
        r = copy.deepcopy(clean(plant, days))
        assert r.time[0] == first_time(days), (r.time[0], first_time(days))
    else:
        r = simulate(plant=plant, weather="almeria", days=days, seed=2, step=60,
                     effects=[f"{effect}@{t0}:{SPECS[effect][plant]}"])
    if post is not None:
        post(r)
    path = tmp_path / f"{plant}.csv"
    r.write(path)
    gh = load_greenhouse(PRESET[plant])
    model = build_model(plant, gh)
    return load_series(path, step=STEP, required=model.requires), gh, model, t0


def start_lag_h(start: str, t0: str) -> float:
    """|estimated start − true start| [h] (``start`` in the findings' ISO form with a Z)."""
    return float(abs(np.datetime64(start.rstrip("Z")) - np.datetime64(t0)) / np.timedelta64(1, "h"))


def first_gain(d) -> float:
    """The held-out free-run MAE cut of a diagnosis [-]."""
    return 1.0 - d.after["free_run"]["mae"] / d.before["free_run"]["mae"]


def check_first_finding(d, effect: str, t0: str) -> None:
    """The first finding names ``effect``, cuts the held-out free-run MAE by 30 % and starts
    near ``t0`` (``START_TOLERANCE_H``)."""
    assert d.findings, f"nothing found; rejected: {d.rejected}"
    first = d.findings[0]
    assert first.effect.name in EQUIVALENT[effect]
    gain = first_gain(d)
    assert gain >= 0.30, f"held-out free-run MAE only cut by {gain:.0%}"
    # the start time is estimated near the truth
    assert first.start is not None
    assert start_lag_h(first.start, t0) <= START_TOLERANCE_H.get(effect, 3.0)


def check_no_effect(d) -> None:
    """On effect-free data the diagnosis never makes the held-out free run worse, and the
    one-step error by at most 20 %; the JSON has its parts."""
    assert d.after["free_run"]["mae"] <= d.before["free_run"]["mae"] + 1e-12
    assert d.after["one_step"]["mae"] <= 1.2 * d.before["one_step"]["mae"]
    out = to_json(d)
    assert set(out) >= {"findings", "before", "after", "unexplained"}
    assert set(out["before"]["free_run"]) == {"mae", "rmse", "maxae", "r2", "ef"}


# -- the shared base calibration --------------------------------------------------------------
CHECK_ENV = "SERRA_CHECK_SHARED_CALIBRATION"
"""Set to 1 to recompute every shared calibration and assert it equals the stored one (the
proof that sharing changes nothing; costs what sharing saves)."""
_CALIBRATIONS: dict[str, tuple] = {}


def _key(base, gh, x: dict, dt: float, s: int, horizon: int, seed: int) -> str:
    """What ``calibrate_base`` reads: the base and greenhouse, the drivers' calibration rows
    [0, s) (it fits and judges on windows inside them only), the grid, the split, the horizon,
    the seed, and the module's switches and iteration counts."""
    h = hashlib.sha256()
    h.update(pickle.dumps((base, gh, float(dt), int(s), int(horizon), int(seed))))
    h.update(pickle.dumps({k: v for k, v in vars(base_module).items() if k.isupper()}))
    for k in sorted(x):
        v = np.ascontiguousarray(np.asarray(x[k])[:s])
        h.update(k.encode() + str(v.dtype).encode() + v.tobytes())
    return h.hexdigest()


def _same(a: tuple, b: tuple) -> bool:
    """Two calibrations equal bit for bit (model, parameters, structure log)."""
    return (pickle.dumps(a[0]) == pickle.dumps(b[0]) and np.array_equal(a[1], b[1])
            and a[2] == b[2])


@contextmanager
def shared_calibration() -> Iterator[None]:
    """``search.calibrate_base`` (what ``diagnose`` and ``search.prepare`` call) computed once
    per distinct input (``_key``) for the duration, each caller getting a deep copy; calls with
    a ``resample`` hook go through as they are."""
    real = base_module.calibrate_base

    def calibrate(base, gh, x, dt, s, horizon, seed, say, resample=None):
        if resample is not None:
            return real(base, gh, x, dt, s, horizon, seed, say, resample)
        key = _key(base, gh, x, dt, s, horizon, seed)
        if key not in _CALIBRATIONS:
            _CALIBRATIONS[key] = copy.deepcopy(real(base, gh, x, dt, s, horizon, seed, say))
        elif os.environ.get(CHECK_ENV) == "1":
            fresh = real(base, gh, x, dt, s, horizon, seed, say)
            assert _same(fresh, _CALIBRATIONS[key]), "a shared calibration differs from its own"
        return copy.deepcopy(_CALIBRATIONS[key])

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(search, "calibrate_base", calibrate)
        yield


# -- fixtures the three test files import (``from tests.diagnose_cases import ...``) ----------
@pytest.fixture(scope="module", autouse=True)
def shared_calibration_in_module() -> Iterator[None]:
    """One base calibration per distinct calibration part for the importing module's cases."""
    with shared_calibration():
        yield


@pytest.fixture
def piece_judge(monkeypatch: pytest.MonkeyPatch) -> None:
    """The judge on 6-hour pieces (``judge.DAY_TEST`` off) for the 6-day records: they test the
    library's naming and starts, and the shipped day test needs ``significance.MIN_DAYS`` held-out
    days after a change where these leave 2 (docs/effects.md, "What switching it on costs on
    short records")."""
    monkeypatch.setattr(judge, "DAY_TEST", False)

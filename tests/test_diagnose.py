"""Diagnosis (issue 4) on the reference simulator's data with undeclared effects: the Almería
house (the prototype box: tests/test_diagnose_box.py; the shipped day test on 10-day records
and effects inside the calibration part: tests/test_diagnose_day_test.py).

Each case simulates 6 days on synthetic Almería weather (seed 2), injects one effect 3.6 days
in (inside the held-out half), resamples to 5 min to keep the suite fast, and runs the whole
diagnosis. The requirement: the first finding names the effect (or its documented equivalent,
docs/effects.md) and cuts the held-out free-run MAE by at least 30 %. The cases, sizes and
tolerances are in tests/diagnose_cases.py; the cases share one base calibration per distinct
calibration part (``shared_calibration``: the effects start after it).

The 6-day cases test the library's naming and start times, not the judge's level, and run with
the piece judge (``piece_judge``): a change at day 3.6 leaves 2 held-out days, on which the
shipped day test cannot judge anything (``significance.MIN_DAYS``). The day test itself is checked on
10-day records with the change at day 5.6 (tests/test_diagnose_day_test.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import EFFECTS, diagnose
from gateway.diagnose.effects import LIBRARY
from tests import diagnose_cases as cases
from tests.diagnose_cases import EQUIVALENT, KNOWN_MISSES, SPECS, piece_judge, shared_calibration_in_module  # noqa: F401 (fixtures)

__all__ = ["DAYS", "EQUIVALENT", "SPECS", "_data"]  # tests/generality/day_test_study.py reads them

DAYS = cases.DAYS
"""Days of the records ``_data`` makes (tests/generality/day_test_study.py sets it)."""


def _data(tmp_path, plant: str, effect: str | None, post=None, at: float = 3.6,
          days: int | None = None):
    """``diagnose_cases.data`` with ``DAYS`` read at call time."""
    return cases.data(tmp_path, plant, effect, post, at, DAYS if days is None else days)


def test_library_is_documented_and_bounded():
    text = open("docs/effects.md", encoding="utf-8").read()
    for e in LIBRARY:
        assert f"`{e.name}`" in text, e.name
        assert e.lower <= e.neutral <= e.upper
    for names in EQUIVALENT.values():
        assert names <= set(EFFECTS)


@pytest.mark.slow
@pytest.mark.usefixtures("piece_judge")
@pytest.mark.parametrize("plant", ["almeria"])
@pytest.mark.parametrize("effect", list(SPECS))
def test_injected_effect_is_first_finding(tmp_path, plant, effect, request):
    if (plant, effect) in KNOWN_MISSES:
        request.applymarker(pytest.mark.xfail(reason="known miss, see docs/effects.md", strict=False))
    series, gh, model, t0 = _data(tmp_path, plant, effect)
    cases.check_first_finding(diagnose(series, gh, model), effect, t0)


@pytest.mark.slow
@pytest.mark.parametrize("plant", ["almeria"])
def test_no_effect_never_makes_heldout_worse(tmp_path, plant):
    series, gh, model, _ = _data(tmp_path, plant, None)
    cases.check_no_effect(diagnose(series, gh, model))


def _misting(r) -> None:
    """An effect not in the library: misting bursts at 11:00 and 15:00 UTC from day 3.6, each
    cooling the air by 2.5 K and relaxing with a 20-minute time constant (both readings)."""
    t = r.time.astype("datetime64[m]").astype(np.int64)
    minute = t % 1440
    start = t[0] + int(3.6 * 1440)
    pulse = np.zeros(len(t))
    for clock in (11 * 60, 15 * 60):
        since = (minute - clock) % 1440
        pulse += np.where((since < 120) & (t >= start), -2.5 * np.exp(-since / 20.0), 0.0)
    r.columns["t_in"] = np.round(r.columns["t_in"] + pulse, 1)


@pytest.mark.slow
def test_effect_outside_library_is_reported_unexplained(tmp_path):
    series, gh, model, _ = _data(tmp_path, "almeria", None, post=_misting)
    d = diagnose(series, gh, model)
    assert d.unexplained, d.signature
    assert "time-of-day" in d.signature

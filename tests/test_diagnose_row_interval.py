"""Logger row intervals (docs/effects.md, "Logger row intervals"): the diagnosis's verdict does
not depend on whether the logger writes a row every 5 or every 15 minutes. Data coarser than
the 300-s fit grid runs on its own grid, with every length the diagnosis uses (horizons, τ
grids, held-out blocks, day-test bins, the judge's minimum lengths) in seconds; the same record
logged at 900 s names the same first finding, near the same start, with about the same
held-out free-run error after it, and effect-free data stays without one."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.diagnose import diagnose
from gateway.series import load_series
from tests import diagnose_cases as cases
from tests.diagnose_cases import piece_judge, shared_calibration_in_module  # noqa: F401 (fixtures)

COARSE_S = 900.0
START_TOLERANCE_H = 12.0
MAE_TOLERANCE = 0.10


def _records(tmp_path, effect: str | None) -> tuple:
    """One 6-day record (diagnose_cases.data, the simulator's 60-s rows) logged as 5-minute and
    as 15-minute block means (a logger averaging over its interval), its greenhouse, model and
    the change's start."""
    series, gh, model, t0 = cases.data(tmp_path, "almeria", effect)
    coarse = load_series(str(tmp_path / "almeria.csv"), step=COARSE_S, required=model.requires)
    assert coarse.step == COARSE_S and len(coarse) * 3 in range(len(series) - 2, len(series) + 3)
    return series, coarse, gh, model, t0


@pytest.mark.usefixtures("piece_judge")
def test_heater_named_alike_at_5_and_15_minute_rows(tmp_path):
    series, rows_900, gh, model, t0 = _records(tmp_path, "heater")
    fine, coarse = diagnose(series, gh, model), diagnose(rows_900, gh, model)
    for d in (fine, coarse):
        cases.check_first_finding(d, "heater", t0)
    assert fine.findings[0].effect.name == coarse.findings[0].effect.name
    lag = np.datetime64(fine.findings[0].start.rstrip("Z")) - np.datetime64(
        coarse.findings[0].start.rstrip("Z"))
    assert abs(lag / np.timedelta64(1, "h")) <= START_TOLERANCE_H
    assert coarse.after["free_run"]["mae"] == pytest.approx(fine.after["free_run"]["mae"],
                                                            rel=MAE_TOLERANCE)


@pytest.mark.usefixtures("piece_judge")
def test_effect_free_stays_quiet_at_15_minute_rows(tmp_path):
    _, rows_900, gh, model, _ = _records(tmp_path, None)
    coarse = diagnose(rows_900, gh, model)
    assert not coarse.findings, [f.effect.name for f in coarse.findings]
    cases.check_no_effect(coarse)

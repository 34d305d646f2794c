"""Residual diagnosis (issue 4): find what a calibrated model lacks, add it, judge on held-out data.

``diagnose(series, gh, model)`` in :mod:`gateway.diagnose.search`; the effect library in
:mod:`gateway.diagnose.effects` (docs/effects.md); residual analysis in
:mod:`gateway.diagnose.residuals`; markdown and PNG report in :mod:`gateway.diagnose.report`.
"""

from gateway.diagnose.effects import EFFECTS, LIBRARY, Effect
from gateway.diagnose.search import Diagnosis, Finding, diagnose, to_json

__all__ = ["EFFECTS", "LIBRARY", "Diagnosis", "Effect", "Finding", "diagnose", "to_json"]

"""Reference greenhouse simulator: real or synthetic weather → kit CSV + truth (issue 4).

See docs/simulator.md. Entry points: :func:`simulate`, :class:`SimResult`, :func:`load_truth`,
the effect classes in :mod:`training.simulate.effects`, and ``python -m training simulate``.
"""

from training.simulate.effects import EFFECTS, Effect, parse_effect
from training.simulate.plant import PRESETS, Plant
from training.simulate.run import SimResult, load_truth, simulate

__all__ = ["EFFECTS", "PRESETS", "Effect", "Plant", "SimResult", "load_truth", "parse_effect",
           "simulate"]

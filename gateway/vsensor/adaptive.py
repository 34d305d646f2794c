"""The adaptive model run twice, as thesis §IV.3.1.1 does: with and without the vent signal.

- With the vents (scenario a): the explicit, vent-based estimate. Its ventilation flow G
  (III.31, with the parameters the online estimator holds at each step) is the sensor's
  training target and, at run time, the reference it is scored against when a CSV carries
  vent openings. ``G`` is taken from the term itself: it is III.32 inverted
  (``G = Q_vent A / (rho c_p ΔT)``) wherever ΔT ≠ 0, and stays defined where ΔT → 0.
- Without them (scenario b): the fluxes the adaptive model finds when it does not know the
  vents; they are the sensor's inputs (gateway.vsensor.features).

The prototype model has no vent term (the kit box has none): for its explicit estimate the
Kittas term (III.31) is added in the prototype's units, with the prototype's own air-exchange
term q_loss (III.19) as the leakage. Only the public API of Model, OnlineEstimator and replay
is used.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from gateway.estimate.online import online_settings
from gateway.estimate.replay import replay
from gateway.greenhouse import Greenhouse
from gateway.model import build_model
from gateway.model.almeria import NaturalVentilation
from gateway.model.model import Model
from gateway.model.prototype import leakage_flow
from gateway.series import Series

VENT_COLUMNS = ("vent_roof", "vent_side")

Overrides = Mapping[str, Mapping[str, float]]


class PrototypeVentilation(NaturalVentilation):
    """Kittas flow through the vents (III.31) as a prototype-model flux: the prototype's
    lumped parameters carry 1/C_a (III.14), so Q / c_p = rho G_vent (T_in - T_out) / S_f
    [K kg m-2 s-1]. Leakage stays with the prototype's q_loss (III.19)."""

    name = "q_vent"
    description = "natural ventilation through the vents, per C_a: -rho G (T_in - T_out) / S_f"
    parameters = NaturalVentilation.parameters[:2]  # c_ven_d, c_ven_w (no leakage)

    def __init__(self, gh: Greenhouse) -> None:
        super().__init__(gh)
        self.rho_cp_a = gh.air_density / gh.floor_area  # the per-C_a version of rho c_p / A
        self.volume = gh.volume

    def flow(self, p, x, t_in, t):
        return super().flow({**p, "c_loss": 0.0}, x, t_in, t)


def explicit_model(kind: str, gh: Greenhouse) -> Model:
    """The ``kind`` model that reads the vent openings (scenario a)."""
    model = build_model(kind, gh)
    if kind == "prototype":
        return model.with_terms(PrototypeVentilation(gh), name="prototype+vents")
    return model


def has_vents(series: Series) -> bool:
    """True when the series carries at least one vent opening."""
    return any(c in series for c in VENT_COLUMNS)


def without_vents(series: Series) -> Series:
    """The same series with the vent columns removed (the model sees closed vents)."""
    cols = {k: v for k, v in series.columns.items() if k not in VENT_COLUMNS}
    return Series(series.time, series.step, cols, series.source, list(series.notices))


def settings_for(model: Model, gh: Greenhouse, overrides: Overrides | None):
    """The model's online settings with ``overrides`` for the groups it has (one set of
    overrides serves both model kinds: the prototype has no radiation group)."""
    groups = {g.output for g in model.online}
    return online_settings(model, gh, {k: v for k, v in (overrides or {}).items() if k in groups})


@dataclass
class AdaptiveRun:
    """One replay of the online estimator, reduced to what the sensor needs (length T)."""

    time: np.ndarray
    x: dict[str, np.ndarray]  # drivers the estimator saw (kit columns and derived)
    fluxes: dict[str, np.ndarray]  # each term's flux [W m-2] with the parameters of step t
    theta: np.ndarray  # (T, k) parameters after the update at t
    names: list[str]
    flow: np.ndarray | None = None  # explicit ventilation flow G [m3 s-1] (with vents only)
    step_ms: float = float("nan")  # median wall time of one estimator update


def run_adaptive(
    kind: str,
    series: Series,
    gh: Greenhouse,
    vents: bool,
    overrides: Overrides | None = None,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
) -> AdaptiveRun:
    """Replay ``series`` through the online estimator of the ``kind`` model, with the vent
    signal (``vents``: scenario a, the explicit flow is computed) or without it (scenario b).

    The estimator starts from the model's published parameters (``Model.defaults``) and uses
    the greenhouse's online settings with ``overrides`` on top (e.g. fewer bats in tests).
    """
    model = explicit_model(kind, gh) if vents else build_model(kind, gh)
    data = series if vents else without_vents(series)
    settings = settings_for(model, gh, overrides)
    result = replay(model, data, gh, model.defaults(gh), settings, seed=seed, horizons=(),
                    progress=progress, score=False)
    theta = result.theta
    x = result.x
    t_in = x["t_in"]
    ok = np.all(np.isfinite(theta), axis=1)
    theta_f = np.where(ok[:, None], theta, model.defaults(gh)[None, :])
    fluxes = {k: np.where(ok, np.broadcast_to(v, t_in.shape), np.nan)
              for k, v in model.fluxes(theta_f, x, t_in).items()}
    flow = None
    if vents:
        term = next(t for t in model.terms if t.name == "q_vent")
        if not isinstance(term, NaturalVentilation):  # explicit_model: Kittas' flow (III.31)
            raise TypeError(f"{model.name}: q_vent is a {type(term).__name__}, which has no flow")
        p = {n: theta_f[:, j] for j, n in enumerate(model.names)}
        flow = np.asarray(term.flow(p, x, t_in, slice(0, len(t_in))), dtype=float)
        if kind == "prototype":  # the prototype's leakage adds to the vents' flow
            flow = flow + leakage_flow(p["c_loss"], gh)
        flow = np.where(ok & np.isfinite(t_in), flow, np.nan)
    ms = result.step_ms[np.isfinite(result.step_ms)]
    return AdaptiveRun(series.time, x, fluxes, theta, list(model.names), flow,
                       float(np.median(ms)) if ms.size else float("nan"))

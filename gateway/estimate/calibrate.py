"""Offline calibration of a model on measured data (thesis §III.4 and §IV.2.2.1.A).

Two stages when the model has a radiation sub-model and the data measures i_in: c_tsw is fitted
on the inside radiation first (III.35, by least squares: ``RadiationSubmodel.fit``, the one fit
the online estimator and the diagnosis use too), then the air-temperature parameters with c_tsw
fixed, because the temperature alone only sees the product C_asw C_tsw.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gateway.estimate.objective import Objective
from gateway.estimate.swarm import Algorithm, SearchResult
from gateway.greenhouse import Greenhouse
from gateway.metrics import metrics
from gateway.model.drivers import prepare_drivers
from gateway.model.model import Model
from gateway.series import Series


@dataclass
class Calibration:
    """Result of ``calibrate``."""

    model: Model
    algorithm: str
    theta: np.ndarray  # (k,)
    cost: float
    history: np.ndarray
    evaluations: int
    seconds: float
    span: tuple[int, int]
    stages: dict[str, SearchResult] = field(default_factory=dict)

    @property
    def params(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.model.names, self.theta, strict=True)}


def calibrate(
    model: Model,
    series: Series,
    gh: Greenhouse,
    algorithm: Algorithm,
    span: tuple[int, int] | None = None,
    mode: str = "one_step",
    seed: int | None = 0,
    base: np.ndarray | None = None,
    free: list[str] | None = None,
    progress: Callable[[str, int, float], None] | None = None,
) -> Calibration:
    """Fit ``model`` on rows ``span`` of ``series`` with ``algorithm``.

    ``free`` names the parameters to fit (default: all); the others keep ``base`` (default:
    the model's defaults for ``gh``).
    """
    rng = np.random.default_rng(seed)
    x = prepare_drivers(series, gh)
    span = span or (0, len(series))
    theta = model.defaults(gh) if base is None else np.array(base, dtype=float)
    lo, hi = model.bounds(gh)
    names = model.names if free is None else list(free)
    t0 = time.perf_counter()
    stages: dict[str, SearchResult] = {}
    rad = model.radiation.parameter.name if model.radiation is not None else None
    if rad in names and "i_in" in series:
        j = model.index(rad)
        assert model.radiation is not None
        fit = model.radiation.fit(x, span, bounds=(lo[j], hi[j]), min_pairs=1)
        if fit is not None:
            theta[j] = fit.value
            stages["radiation"] = SearchResult(np.array([fit.value]), fit.cost,
                                               np.array([fit.cost]), 1, 0)
            if progress is not None:
                progress("radiation", 0, fit.cost)
    # Without measured i_in, c_tsw is not separable from c_asw: it keeps its base value.
    temp = [model.index(n) for n in names if n != rad]
    obj = Objective(model, x, gh, series.step, np.array(temp), theta, [span], mode=mode)
    res = algorithm(obj, lo[temp], hi[temp], rng=rng, progress=_stage(progress, "temperature"))
    theta[temp] = res.best
    stages["temperature"] = res
    return Calibration(
        model=model,
        algorithm=algorithm.name,
        theta=theta,
        cost=res.cost,
        history=res.history,
        evaluations=sum(s.evaluations for s in stages.values()),
        seconds=time.perf_counter() - t0,
        span=span,
        stages=stages,
    )


def _stage(progress, name):
    if progress is None:
        return None
    return lambda it, cost: progress(name, it, cost)


def evaluate(
    model: Model, theta: np.ndarray, series: Series, gh: Greenhouse, span: tuple[int, int]
) -> dict[str, dict[str, float] | None] | None:
    """One-step and free-run metrics of ``theta`` on rows ``span``, and beside them the naive
    baseline ``persistence`` (T_in[t + 1] = T_in[t], on the samples the one-step prediction
    covers); None for an empty span."""
    a, b = span
    if b - a < 2:
        return None
    part = series.slice(a, b)
    x = prepare_drivers(part, gh)
    theta2 = np.atleast_2d(theta)
    one = model.one_step(theta2, x, gh, series.step)[0]
    free = model.free_run(theta2, x, gh, series.step)[0]
    meas = x["t_in"]
    held = np.where(np.isfinite(one[1:]), meas[:-1], np.nan)
    return {
        "one_step": metrics(meas[1:], one[1:]),
        "free_run": metrics(meas[1:], free[1:]),
        "persistence": metrics(meas[1:], held),
    }

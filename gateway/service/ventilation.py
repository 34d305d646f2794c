"""The virtual ventilation sensor in the live service, and the estimator that feeds it.

A sensor reads the heat fluxes of the adaptive model kind it was trained on (its ONNX metadata's
``model_kind``, ``prototype`` or ``almeria``: docs/vsensor.md). When the greenhouse's forecasting
model is that kind, the forecasting estimator's fluxes feed it (one estimator). When it is another
(e.g. ``prototype+vent_control``), or when the sensor was trained on an estimator with other
settings (its metadata's ``online_overrides``, e.g. 15 air-temperature iterations against the
live 50), a second :class:`OnlineEstimator` of the sensor's kind and training settings steps on
the same minutes' drivers with its own parameters and state: the sensor reads the fluxes it was
trained on, as ``python -m gateway vsensor`` computes them. Its fluxes go only to the sensor (the
published fluxes and forecasts stay the forecasting model's). Its snapshot rides in the pipeline's
saved state under :data:`STATE_KEY`, so a restart resumes it too; the sensor's own history (its
filters, input delays and fed-back outputs) rides under :data:`HISTORY_KEY`, so the closed loop
goes on where it stopped instead of settling again.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.estimate.online import OnlineEstimator, online_settings
from gateway.estimate.settings import GroupSettings
from gateway.greenhouse import Greenhouse
from gateway.model import build_model
from gateway.model.model import Model
from gateway.service.minutes import KIT_COLUMNS

VENT_GAP_S = 90.0
"""A longer step between two calls restarts the sensor's history (its filters, input delays and
fed-back outputs), as the estimator restarts its window after a gap."""
STATE_KEY = "vsensor_estimator"
"""Where the sensor's own estimator's snapshot sits in the pipeline's saved state."""
HISTORY_KEY = "vsensor_history"
"""Where the sensor's history (runtime.VentSensor.snapshot and the minute it last stepped) sits."""


@dataclass
class VentilationEstimate:
    flow: float  # [m3 s-1]
    heat_loss: float  # [W m-2 of floor]
    out_of_range: bool = False


Ventilation = Callable[[float, Mapping[str, float], Mapping[str, float]], VentilationEstimate | None]
"""The sensor's per-minute call: ``(t, drivers of the minute, heat fluxes [W m-2]) → estimate or
None``."""


@dataclass(frozen=True)
class VentilationSensor:
    """The per-minute call, the model whose fluxes it reads (built for the greenhouse) and the
    online estimator's settings it was trained with (the model's, with the metadata's
    ``online_overrides``; None: the model's own for the greenhouse)."""

    step: Ventilation
    model: Model
    settings: tuple[GroupSettings, ...] | None = None
    history: Callable[[], dict] | None = None  # the sensor's history, JSON-able
    resume: Callable[[Mapping], None] | None = None  # ValueError when not this sensor's


def load_ventilation(path: Path, gh: Greenhouse) -> VentilationSensor:
    """The ONNX sensor (gateway/vsensor) at ``path`` for the model kind it was trained on.

    ValueError (naming the file) when it cannot be loaded or when that kind needs a column a
    Serra kit does not measure (the ``almeria`` kind needs ``t_soil``). A step with flagged inputs
    (missing, outside the training ranges, another greenhouse's vents) is returned with
    ``out_of_range`` set."""
    from gateway.vsensor import VentSensor
    from gateway.vsensor.adaptive import settings_for

    if not path.exists():
        raise ValueError(f"{path}: no such ONNX model")
    sensor = VentSensor(path, gh, None, threads=1)  # ModelMismatch is a ValueError
    model = build_model(sensor.kind, gh)
    missing = [c for c in model.requires if c not in KIT_COLUMNS]
    if missing:
        raise ValueError(f"{path}: trained on the fluxes of the '{sensor.kind}' model, which needs "
                         f"{', '.join(missing)}, which a Serra kit does not measure (kit: "
                         f"{', '.join(KIT_COLUMNS)}); use a sensor trained with --model prototype")
    last: list[float] = []

    def step(t: float, drivers: Mapping[str, float],
             fluxes: Mapping[str, float]) -> VentilationEstimate:
        if last and not 0.0 < t - last[0] <= VENT_GAP_S:  # a gap, or time went back: anew
            sensor.reset()
        last[:] = [t]
        est = sensor.step(drivers, fluxes)
        return VentilationEstimate(est.flow, est.q_vent, out_of_range=not est.valid)

    try:  # the estimator settings it was trained with: what it must be fed with
        settings = settings_for(model, gh, sensor.info.meta.get("online_overrides"))
    except (ValueError, TypeError, AttributeError) as e:
        raise ValueError(f"{path}: its metadata's online_overrides: {e}") from None

    def history() -> dict:
        return {"t": last[0] if last else None, **sensor.snapshot()}

    def resume(snap: Mapping) -> None:
        t = snap.get("t")
        sensor.restore(snap)
        last[:] = [] if t is None else [float(t)]

    return VentilationSensor(step, model, settings, history, resume)


class SensorFeed:
    """The sensor and what feeds it: the forecasting estimator, or its own estimator."""

    def __init__(self, sensor: VentilationSensor, model: Model, gh: Greenhouse, seed: int,
                 dt: float) -> None:
        self.sensor = sensor
        self._fresh = (gh, seed, dt)
        self.own: OnlineEstimator | None = None
        self.why = ""
        self.settings = sensor.settings or online_settings(sensor.model, gh)
        if sensor.model.name != model.name:
            self.why = "its kind"
        elif self.settings != online_settings(model, gh):
            self.why = "its training settings"
        if self.why:
            self._start_fresh()

    def _start_fresh(self) -> None:
        gh, seed, dt = self._fresh
        m = self.sensor.model
        # the training's settings, the forecasting estimator's seed: the same flows whatever the
        # forecasting model (tests/test_gateway_ventilation.py)
        self.own = OnlineEstimator(m, gh, None, self.settings, dt=dt, seed=seed)

    def describe(self) -> str:
        return "" if self.own is None else (
            f"; ventilation sensor fed by its own '{self.sensor.model.name}' estimator "
            f"({self.why})")

    def update(self, values: Mapping[str, float], time: np.datetime64) -> None:
        """Step the sensor's own estimator (if any) on the minute the forecasting one just took."""
        if self.own is not None:
            self.own.update(values, time=time)

    def restart_window(self) -> None:
        if self.own is not None:
            self.own.restart_window()

    def estimate(self, t: float, t_in: float, drivers: Mapping[str, float],
                 fluxes: Mapping[str, float]) -> VentilationEstimate | None:
        """The sensor's estimate for minute ``t``: ``drivers`` and ``fluxes`` are the forecasting
        estimator's, used when the sensor reads that model; else its own estimator's."""
        if self.own is not None:
            drivers = self.own.last_row
            fluxes = self.own.model.fluxes_at(self.own.theta, drivers, t_in)
        return self.sensor.step(t, drivers, fluxes) if fluxes else None

    def snapshot(self) -> dict | None:
        return None if self.own is None else self.own.snapshot()

    def history(self) -> dict | None:
        return None if self.sensor.history is None else self.sensor.history()

    def restore(self, saved: Mapping) -> str:
        """Resume from the pipeline's saved state (as saved, before any migration) the sensor's
        history and the own estimator: its snapshot under :data:`STATE_KEY`, or the forecasting
        estimator's when that was of the sensor's kind (the greenhouse's ``model =`` changed from
        it). Else they start anew. Returns the note for the start's log line; the forecasting
        state is never touched."""
        return self._restore_own(saved) + self._restore_history(saved.get(HISTORY_KEY))

    def _restore_history(self, snap) -> str:
        if self.sensor.resume is None or not isinstance(snap, Mapping):
            return ""
        try:
            self.sensor.resume(snap)
        except (ValueError, KeyError, TypeError) as e:
            return f"; ventilation sensor's history starts anew ({e})"
        return "; ventilation sensor's history resumed"

    def _restore_own(self, saved: Mapping) -> str:
        if self.own is None:
            return ""
        kind = self.sensor.model.name
        for snap, how in ((saved.get(STATE_KEY), "resumed"),
                          (saved, "resumed from the saved forecasting estimator")):
            if not isinstance(snap, Mapping) or snap.get("model") != kind:
                continue
            try:
                self.own.restore(snap)
                return f"; ventilation sensor's '{kind}' estimator {how}"
            except (ValueError, KeyError, TypeError, IndexError) as e:
                self._start_fresh()  # a restore that failed half-way leaves nothing behind
                return f"; ventilation sensor's '{kind}' estimator starts anew (its state: {e})"
        return f"; ventilation sensor's '{kind}' estimator starts anew (no saved state of it)"

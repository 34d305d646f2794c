"""The virtual ventilation sensor at run time: an ONNX model, one step a minute, closed loop.

    sensor = VentSensor("almeria.onnx", greenhouse, "almeria")   # once per greenhouse
    est = sensor.step(measurements, fluxes)                       # every minute
    est.flow [m3 s-1], est.q_vent [W m-2], est.valid, est.out_of_range, sensor.counts

``measurements``: kit column → value (t_in, t_out, rh_in, rh_out, wind); ``fluxes``: term name →
flux of the adaptive model run without the vent signal (``fluxes_now``). The sensor refuses a
model whose metadata does not match the features this code computes for the running model kind
(:class:`ModelMismatch` names the difference). It feeds back its own past outputs, clamps every
output to [0, the physical maximum of this house now], flags inputs that are missing or outside
the training ranges and counts them. No NaN and no negative flow ever leaves it.
``VentSensor(..., clamp_inputs=True)`` (off by default) also feeds every filtered input outside
its padded training range at that range's bound (``loop.padded_ranges``; still flagged, and
counted in ``counts.inputs_clamped``), as ``loop.closed_loop(..., bounds=...)`` does in batch.
``io_binding=False``: plain ``session.run`` instead of the same bits through ``binding.BoundRun``.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.vsensor.binding import BoundRun
from gateway.vsensor.features import (
    EXTRAS,
    INPUT_DELAYS,
    OUTPUT_DELAYS,
    extras_of,
    filter_gains,
    flow_limits,
    flux_names,
    greenhouse_signature,
    rho_cp_per_area,
    signature_mismatch,
)
from gateway.vsensor.loop import padded_ranges
from gateway.vsensor.model_info import (
    ModelMismatch,
    check_model,
    check_target,
    graph_histories,
    read_info,
)


@dataclass(frozen=True)
class VentEstimate:
    """One step's output. ``flow`` [m3 s-1] ≥ 0 and ``q_vent`` [W m-2] (III.32, positive when
    the house loses heat) are always finite. ``valid`` is False when anything is flagged:
    ``missing`` (inputs absent or non-finite, the filter held), ``out_of_range`` (inputs
    outside the training ranges), ``other_greenhouse`` (the model was trained on another house),
    ``clamped`` (the network asked for a flow outside [0, physical maximum])."""

    flow: float
    q_vent: float
    valid: bool
    out_of_range: tuple[str, ...] = ()
    missing: tuple[str, ...] = ()
    clamped: bool = False
    other_greenhouse: bool = False


@dataclass
class SensorCounts:
    """Running counts since the sensor was built (for the health page and the CLI report)."""

    steps: int = 0
    flagged: int = 0  # steps with valid False
    out_of_range_steps: int = 0
    missing_steps: int = 0
    clamped: int = 0
    non_finite_output: int = 0
    out_of_range: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)
    inputs_clamped: int = 0  # steps with an input fed at its bound (clamp_inputs only)


class VentSensor:
    """The deployed sensor for one greenhouse (see the module docstring)."""

    def __init__(self, model_path: str | Path, gh: Greenhouse, model_kind: str | None,
                 threads: int = 1, clamp_inputs: bool = False, io_binding: bool = True) -> None:
        """``model_kind``: the model whose fluxes will be fed (a model trained on another kind
        is refused); None: the kind the model was trained on (its metadata's ``model_kind``),
        for a caller that feeds whatever the model reads (gateway/service/ventilation.py)."""
        from gateway.vsensor.ort import load

        ort = load()

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(model_path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ModelMismatch(f"{model_path}: cannot load as an ONNX model: {exc}") from None
        self.info = read_info(model_path, self.session)
        model_kind = self.info.kind if model_kind is None else model_kind
        shape = self.session.get_inputs()[0].shape
        check_model(self.info, model_kind, shape[-1] if isinstance(shape[-1], int) else None)
        self.gh, self.kind = gh, model_kind
        trained = self.info.greenhouse.get("signature", {})
        self.mismatch = signature_mismatch(trained, greenhouse_signature(gh))
        if trained == greenhouse_signature(gh):  # the house it was trained on: the code's driver
            check_target(self.info, gh)
        self.limits = flow_limits(gh, model_kind)
        self.rho_cp_a = rho_cp_per_area(gh)
        self.extra = extras_of(model_kind, self.info.names)
        self._extra_fns = [EXTRAS[n][1] for n in self.extra]
        self._gains = [float(a) for a in filter_gains(model_kind, extra=self.extra)]
        lo, hi = padded_ranges(self.info.ranges)
        self._lo, self._hi = [float(v) for v in lo], [float(v) for v in hi]
        self.clamp_inputs = bool(clamp_inputs)
        self._flux_names = flux_names(model_kind)
        self._out = [self.session.get_outputs()[0].name]
        self.histories = graph_histories(model_path, self.session, self.info)
        self.model_id = hashlib.sha256(Path(model_path).read_bytes()).hexdigest()[:16]
        self._feeds: dict[str, np.ndarray] = {}
        self._run = BoundRun(self.session, self.histories) if io_binding else self._plain_run
        self.counts = SensorCounts()
        self.reset()

    def reset(self) -> None:
        """Forget the history (filter states, delays, past outputs), as after a restart."""
        n_f = len(self.info.names)
        self._state: list[float] = [math.nan] * n_f
        self._u = np.zeros((1, len(INPUT_DELAYS), n_f), dtype=np.float32)
        # one past-output history per member on its own past (K = 1: the graph reads (1, 5))
        self._y = np.full((1, self.histories, len(OUTPUT_DELAYS)), self.info.y0, dtype=np.float32)
        self._y_feed = self._y if self.histories > 1 else self._y[:, 0]
        self._started = False
        self._last_dt = 0.0

    def snapshot(self) -> dict:
        """The history (filter states, input delays, past outputs) as JSON-able values, for a
        restart to resume the closed loop where it stopped (:meth:`restore`)."""
        return {"model": self.model_id, "state": list(self._state), "u": self._u.tolist(),
                "y": self._y.tolist(), "started": self._started, "last_dt": self._last_dt}

    def restore(self, snap: Mapping) -> None:
        """Resume a :meth:`snapshot` of this same model file (ValueError otherwise: the
        history is left as it was)."""
        if snap.get("model") != self.model_id:
            raise ValueError(f"the saved history is of another model ({snap.get('model')!r}, "
                             f"this one is {self.model_id!r})")
        state = [float(v) for v in snap["state"]]
        u = np.array(snap["u"], dtype=np.float32, order="C")  # own C copies: bound in place
        y = np.array(snap["y"], dtype=np.float32, order="C")
        if len(state) != len(self._state) or u.shape != self._u.shape or y.shape != self._y.shape:
            raise ValueError("the saved history has the wrong shape")
        started, last_dt = bool(snap["started"]), float(snap["last_dt"])
        self._state, self._u, self._y = state, u, y
        self._y_feed = self._y if self.histories > 1 else self._y[:, 0]
        self._started, self._last_dt = started, last_dt

    def step(self, measurements: Mapping[str, float], fluxes: Mapping[str, float]) -> VentEstimate:
        """One minute: measurements (kit columns) and the no-vent adaptive model's fluxes."""
        m = measurements
        dt = _num(m.get("t_in")) - _num(m.get("t_out"))
        raw = [_num(m.get("wind")), dt, _num(m.get("rh_in")) - _num(m.get("rh_out"))]
        raw += [_num(fluxes.get(n)) for n in self._flux_names]
        if self._extra_fns:  # the same functions as training's raw_features, on this minute
            def col(name: str) -> np.ndarray:
                return np.array([_num(m.get(name))])
            raw += [float(f(col)[0]) for f in self._extra_fns]
        row, missing, outside = self._filter(raw)
        if outside and self.clamp_inputs:
            self.counts.inputs_clamped += 1
        if not self._started:
            self._u[0, :] = row
            self._started = True
        else:
            self._u[0, 1:] = self._u[0, :-1].copy()
            self._u[0, 0] = row
        out = self._run(self._u, self._y_feed)[0]  # BoundRun: re-binds a replaced _u / _y_feed
        upper = self.limits.upper_now(dt, _num(m.get("t_out")), raw[0])
        ys, clamped = [], False  # every history's output held, clipped, then averaged
        for j in range(self.histories):
            v, cl = self._limit(float(out[j]), float(self._y[0, j, 0]), upper)
            ys.append(v)
            clamped |= cl
        self._y[0, :, 1:] = self._y[0, :, :-1].copy()
        self._y[0, :, 0] = ys
        y = sum(ys) / self.histories
        if math.isfinite(dt):
            self._last_dt = dt
        q = self.rho_cp_a * y * self._last_dt + 0.0  # + 0.0: no "-0" for a closed house
        est = VentEstimate(y, q, not (missing or outside or self.mismatch), outside, missing,
                           clamped, bool(self.mismatch))
        self._count(est)
        return est

    def _plain_run(self, u: np.ndarray, y_past: np.ndarray) -> np.ndarray:
        self._feeds["u"], self._feeds["y_past"] = u, y_past
        return self.session.run(self._out, self._feeds)[0]

    def _limit(self, y: float, last: float, upper: float) -> tuple[float, bool]:
        """A network output held when non-finite and clipped to [0, upper]; clipped or not."""
        if not math.isfinite(y):
            self.counts.non_finite_output += 1
            y = last
        return min(max(y, 0.0), upper), not 0.0 <= y <= upper

    def _filter(self, raw: list[float]) -> tuple[list[float], tuple[str, ...], tuple[str, ...]]:
        """Low-pass each input (features.low_pass, one row); NaN holds the filter. With
        ``clamp_inputs`` an input flagged outside its padded range is fed at the bound it
        crossed; the filter's state itself is never clamped (the batch clamps the filtered
        series, loop.closed_loop)."""
        names, state, gains = self.info.names, self._state, self._gains
        row, missing, outside = [], [], []
        for i, v in enumerate(raw):
            if math.isfinite(v):
                state[i] = v if math.isnan(state[i]) else state[i] + gains[i] * (v - state[i])
            else:
                missing.append(names[i])
            s = state[i]
            if math.isnan(s):
                s = float(self.info.mean[i])  # never seen yet: the training mean
            elif not self._lo[i] <= s <= self._hi[i]:
                outside.append(names[i])
            if self.clamp_inputs:  # the mean too, as the batch clips after fill_missing
                s = min(max(s, self._lo[i]), self._hi[i])
            row.append(s)
        return row, tuple(missing), tuple(outside)

    def _count(self, est: VentEstimate) -> None:
        c = self.counts
        c.steps += 1
        c.flagged += not est.valid
        c.clamped += est.clamped
        c.out_of_range_steps += bool(est.out_of_range)
        c.missing_steps += bool(est.missing)
        for n in est.out_of_range:
            c.out_of_range[n] = c.out_of_range.get(n, 0) + 1
        for n in est.missing:
            c.missing[n] = c.missing.get(n, 0) + 1


def _num(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def fluxes_now(estimator) -> dict[str, float]:
    """The fluxes [W m-2] of an ``OnlineEstimator`` after its ``update`` for this minute
    (``Model.fluxes_at`` on the sample just checked, with the parameters just estimated, along
    the measured inside temperature); {} when one is missing or not finite."""
    row = estimator.last_row
    return estimator.model.fluxes_at(estimator.theta, row, _num(row.get("t_in")))

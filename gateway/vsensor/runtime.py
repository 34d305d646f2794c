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
import json
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
    STEP_S,
    check_names,
    extras_of,
    features,
    filter_gains,
    flow_limits,
    flux_names,
    greenhouse_signature,
    rho_cp_per_area,
    signature_mismatch,
)
from gateway.vsensor.loop import padded_ranges

FORMAT = "serra-vsensor/1"
TARGET_KINDS = ("flow", "opening", "mixed")
"""What the graph's network predicts (metadata ``target_kind``, absent: ``flow``); either way the
graph takes past flows and gives a flow. ``opening``: G / D, the graph computing the ventilation
driver D from its inputs with the constants of ``opening_driver`` (docs/vsensor.md). ``mixed``:
an ensemble whose members learn ``member_targets`` (each ``flow`` or ``opening``), averaged as
flows in the graph."""
MEMBER_TARGETS = ("flow", "opening")


class ModelMismatch(ValueError):
    """The ONNX model does not fit the code that would feed it; the message says how."""


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


@dataclass(frozen=True)
class ModelInfo:
    """What the model's metadata says (read once at load)."""

    path: str
    kind: str  # model kind the fluxes come from
    network: str  # pca_narx | narx_no_pca | linear_arx
    names: tuple[str, ...]
    ranges: np.ndarray  # (F, 2) training min, max of each filtered input
    mean: np.ndarray  # (F,) training mean (stands in for an input never seen)
    y0: float  # past outputs before the first step [m3 s-1]
    greenhouse: dict
    meta: dict


def read_info(path: str | Path, session) -> ModelInfo:
    raw = dict(session.get_modelmeta().custom_metadata_map)
    if raw.get("format") != FORMAT:
        raise ModelMismatch(f"{path}: not a Serra ventilation sensor model (format "
                            f"{raw.get('format')!r}, expected {FORMAT!r})")
    meta = {k: (v if k == "format" else _json(v)) for k, v in raw.items()}
    missing = [k for k in ("features", "model_kind", "training_ranges", "input_mean", "y0") if k not in meta]
    if missing:
        raise ModelMismatch(f"{path}: metadata lacks {', '.join(missing)}")
    feats = meta["features"]
    names = tuple(f.get("name", "?") for f in feats)
    nan2 = [math.nan, math.nan]
    return ModelInfo(
        path=str(path), kind=meta["model_kind"], network=meta.get("network", "?"), names=names,
        ranges=np.array([meta["training_ranges"].get(n, nan2) for n in names], dtype=float),
        mean=np.array([meta["input_mean"].get(n, math.nan) for n in names], dtype=float),
        y0=float(meta["y0"]), greenhouse=meta.get("greenhouse", {}), meta=meta,
    )


def _json(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return text


def check_model(info: ModelInfo, kind: str, n_graph_features: int | None = None) -> None:
    """Raise :class:`ModelMismatch` unless the model reads what this code computes for ``kind``
    (with the extra features the model names, when the code knows them)."""
    where = info.path
    if info.kind != kind:
        raise ModelMismatch(f"{where}: trained on fluxes of the '{info.kind}' model, but the "
                            f"gateway runs the '{kind}' model")
    extra = tuple(n for n in extras_of(kind, info.names) if n in EXTRAS)
    code = features(kind, extra)
    diff = check_names([f.name for f in code], info.names)
    if diff:
        raise ModelMismatch(f"{where}: {diff} (model kind '{kind}')")
    meta_feats = info.meta["features"]
    for f, m in zip(code, meta_feats, strict=True):
        if f.unit != m.get("unit"):
            raise ModelMismatch(
                f"{where}: feature {f.name} in {m.get('unit')!r}, the code gives {f.unit!r}")
        if not math.isclose(f.tau, float(m.get("tau_s", -1)), abs_tol=1e-9):
            raise ModelMismatch(f"{where}: feature {f.name} filtered with tau {m.get('tau_s')} s, "
                                f"the code uses {f.tau:g} s")
    for key, value in (("input_delays", INPUT_DELAYS), ("output_delays", OUTPUT_DELAYS)):
        if list(info.meta.get(key, [])) != list(value):
            raise ModelMismatch(
                f"{where}: {key} {info.meta.get(key)} but the code feeds {list(value)}")
    if float(info.meta.get("step_s", -1)) != STEP_S:
        raise ModelMismatch(
            f"{where}: trained at a {info.meta.get('step_s')} s step, the code runs {STEP_S:g} s")
    bad = [n for n, r, m in zip(info.names, info.ranges, info.mean, strict=True)
           if not (np.all(np.isfinite(r)) and np.isfinite(m))]
    if bad:
        raise ModelMismatch(f"{where}: no training range or mean for {', '.join(bad)}")
    if n_graph_features is not None and n_graph_features != len(code):
        raise ModelMismatch(
            f"{where}: the graph takes {n_graph_features} inputs, the metadata names {len(code)}")
    check_target(info)


def check_target(info: ModelInfo, gh: Greenhouse | None = None) -> None:
    """Raise :class:`ModelMismatch` for a target kind this code does not serve, a mixed model
    whose members' targets it does not, or an opening (or mixed) model whose driver is not the
    model layer's (``ventilation_driver``) for ``gh``, the house it was trained on (checked when
    ``gh`` is that house: a changed III.31 needs a retrain)."""
    kind = info.meta.get("target_kind", "flow")
    if kind not in TARGET_KINDS:
        raise ModelMismatch(f"{info.path}: target kind {kind!r}, this code serves {TARGET_KINDS}")
    if kind == "mixed" and not _mixed_needs_driver(info):  # flow members only: no driver
        return
    if kind == "flow":
        return
    drv = info.meta.get("opening_driver")
    if not isinstance(drv, dict) or not all(k in drv for k in ("b", "w", "floor", "t_out_ref_c",
                                                               "floor_wind_m_s")):
        raise ModelMismatch(f"{info.path}: an opening model without its driver's constants")
    if gh is None:
        return
    from gateway.model.almeria import driver_constants

    code = dict(zip(("b", "w", "floor"), driver_constants(gh, float(drv["t_out_ref_c"]),
                                                          float(drv["floor_wind_m_s"])),
                    strict=True))
    for k, v in code.items():
        if not math.isclose(float(drv[k]), v, rel_tol=1e-6):
            raise ModelMismatch(f"{info.path}: opening driver {k} {drv[k]} but the model layer "
                                f"gives {v:.6g} for this house: retrain")


def _mixed_needs_driver(info: ModelInfo) -> bool:
    """Raise :class:`ModelMismatch` unless a mixed model names its members' targets (two or
    more, each one this code serves, one per output history with own feedback); True when one
    of them is an opening member (whose driver is then checked)."""
    members = info.meta.get("member_targets")
    if not isinstance(members, list) or len(members) < 2:
        raise ModelMismatch(f"{info.path}: a mixed model without its members' targets")
    bad = sorted({str(m) for m in members} - set(MEMBER_TARGETS))
    if bad:
        raise ModelMismatch(f"{info.path}: member target {', '.join(bad)}, this code serves "
                            f"{MEMBER_TARGETS}")
    k = int(info.meta.get("feedback_histories", 1))
    if k > 1 and k != len(members):
        raise ModelMismatch(f"{info.path}: {len(members)} member targets for {k} output histories")
    return "opening" in members


class VentSensor:
    """The deployed sensor for one greenhouse (see the module docstring)."""

    def __init__(self, model_path: str | Path, gh: Greenhouse, model_kind: str | None,
                 threads: int = 1, clamp_inputs: bool = False, io_binding: bool = True) -> None:
        """``model_kind``: the model whose fluxes will be fed (a model trained on another kind
        is refused); None: the kind the model was trained on (its metadata's ``model_kind``),
        for a caller that feeds whatever the model reads (gateway/service/ventilation.py)."""
        import onnxruntime as ort

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
        self.histories = _histories(model_path, self.session, self.info)
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


def _histories(path, session, info: ModelInfo) -> int:
    """Output histories the graph keeps: 1 (``y_past`` (N, 5)), or K for an ensemble whose
    members each hear their own past (``y_past`` (N, K, 5), metadata ``feedback_histories``)."""
    shape = next(i.shape for i in session.get_inputs() if i.name == "y_past")
    k = shape[1] if len(shape) == 3 else 1
    want = int(info.meta.get("feedback_histories", 1))
    if not isinstance(k, int) or k != want:
        raise ModelMismatch(f"{path}: the graph keeps {k} output histories, the metadata says {want}")
    return k


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

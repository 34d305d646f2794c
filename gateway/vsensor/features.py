"""What the virtual ventilation sensor reads (thesis §IV.3.1.1) and the III.32 conversions.

Inputs (one row per model step): the outside wind, the inside–outside temperature and relative
humidity differences, and every heat flux of the adaptive model run *without* the vent signal
(scenario b of §IV.3.1.1). One list per model kind; the order is the order of the ONNX input
and is written into the model's metadata, so a model trained on other features is refused.

Departure from the thesis (docs/vsensor.md): scenario b there sets Q_ven = 0. The almeria model
keeps its leakage term ``q_vent`` without openings (G = c_loss, adapted at every step), and the
prototype its air-exchange term ``q_loss``; both are where the adaptive model puts part of the
missing ventilation, so they are inputs like the other fluxes.

Filtering (§IV.3.1.1, "some of them were filtered"): a causal first-order low-pass with a time
constant per feature (wind gusts; the minute-to-minute jitter of the online estimator's fluxes),
the same code in training and at run time, so a step sees exactly what training saw.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import psychrometrics as psy


@dataclass(frozen=True)
class Feature:
    """One input of the sensor: ``name``, ``unit``, meaning, low-pass time constant [s]."""

    name: str
    unit: str
    meaning: str
    tau: float = 0.0


_MEASURED = (
    Feature("wind", "m s-1", "outside wind speed (D_ws,e)", 600.0),
    Feature("dt_in_out", "K", "inside minus outside air temperature (T_air,diff)"),
    Feature("drh_in_out", "%", "inside minus outside relative humidity (H_air,diff)"),
)
_FLUX_TAU = 300.0
_FLUXES = {
    "almeria": (
        ("q_sol", "short-wave absorbed by the air (Q_sol,a, III.25)"),
        ("q_cnv_ss", "soil surface convection (Q_cnv,ss-a, III.26)"),
        ("q_cnd_cnv", "cover convection-conduction (Q_cnd-cnv,a-e, III.27)"),
        ("q_trp", "crop transpiration (Q_trp,cr, III.28-29)"),
        ("q_vent", "leakage only, no vent signal (III.31-32 with closed vents)"),
    ),
    "prototype": (
        ("q_solar", "solar gain (III.15), per C_a"),
        ("q_cnv_cnd", "cover convection-conduction (III.17), per C_a"),
        ("q_loss", "air exchange (III.19), per C_a"),
        ("q_thermal", "long-wave loss to the sky (III.21), per C_a"),
    ),
}
_FLUX_UNIT = {"almeria": "W m-2", "prototype": "K kg m-2 s-1"}
MODEL_KINDS = tuple(_FLUXES)

INPUT_DELAYS = (0, 1, 2, 3, 4, 5)
"""Input delays of the NARX [steps] (§IV.3.2.2: a tapped delay line from 0 to 5)."""
OUTPUT_DELAYS = (1, 2, 3, 4, 5)
"""Output (feedback) delays [steps] (§IV.3.2.2: from 1 to 5)."""
STEP_S = 60.0
"""Model step [s]: the online estimator's, one sample a minute."""


def _dvp(col: Callable[[str], np.ndarray]) -> np.ndarray:
    return psy.vapour_pressure(col("t_in"), col("rh_in")) - psy.vapour_pressure(col("t_out"), col("rh_out"))


def _vpd_in(col: Callable[[str], np.ndarray]) -> np.ndarray:
    return psy.vapour_pressure_deficit(col("t_in"), col("rh_in"))


def _wind_dt(col: Callable[[str], np.ndarray]) -> np.ndarray:
    return col("wind") * (col("t_in") - col("t_out"))


EXTRAS: dict[str, tuple[Feature, Callable[[Callable[[str], np.ndarray]], np.ndarray]]] = {
    "dvp_in_out": (Feature("dvp_in_out", "kPa", "inside minus outside vapour pressure (the "
                           "humidity balance's driving difference, III.3-5)"), _dvp),
    "vpd_in": (Feature("vpd_in", "kPa", "inside vapour pressure deficit p_ws(T_in) - p_w,in "
                       "(III.4-5): it drives the transpiration the almeria model's q_trp "
                       "carries and the prototype's fluxes lack"), _vpd_in),
    "wind_dt": (Feature("wind_dt", "m s-1 K", "wind times (T_in - T_out) (open vents: G grows "
                        "with the wind, so the product follows the heat to be removed)", 600.0),
                _wind_dt),
}
"""Optional derived inputs after the fluxes (``--extra-features``; a model's metadata names the
ones it was trained with and the runtime computes them): name → (feature, f(column getter))."""


INPUT_COLUMNS: dict[str, tuple[str, ...]] = {
    "wind": ("wind",),
    "dt_in_out": ("t_in", "t_out"),
    "drh_in_out": ("rh_in", "rh_out"),
    "dvp_in_out": ("t_in", "rh_in", "t_out", "rh_out"),
    "vpd_in": ("t_in", "rh_in"),
    "wind_dt": ("wind", "t_in", "t_out"),
}
"""The kit columns each measured input is made from (:func:`raw_features`); the flux inputs
come from the adaptive model, whose own columns are its ``Model.requires``."""


def columns_read(kind: str, extra: Sequence[str] = ()) -> dict[str, tuple[str, ...]]:
    """Kit column → the inputs made from it, of a sensor fed by ``kind`` fluxes with the
    ``extra`` inputs (a column missing from the data makes those inputs NaN on every row)."""
    out: dict[str, list[str]] = {}
    for f in features(kind, extra):
        for c in INPUT_COLUMNS.get(f.name, ()):
            out.setdefault(c, []).append(f.name)
    return {c: tuple(names) for c, names in out.items()}


def features(kind: str, extra: Sequence[str] = ()) -> tuple[Feature, ...]:
    """The sensor's inputs, in order, for fluxes of the ``kind`` model (plus ``extra``)."""
    if kind not in _FLUXES:
        raise ValueError(f"unknown model kind '{kind}' (choose from {', '.join(MODEL_KINDS)})")
    unknown = [n for n in extra if n not in EXTRAS]
    if unknown:
        raise ValueError(f"unknown extra feature(s) {', '.join(unknown)} (choose from "
                         f"{', '.join(EXTRAS)})")
    unit = _FLUX_UNIT[kind]
    return (_MEASURED + tuple(Feature(n, unit, m, _FLUX_TAU) for n, m in _FLUXES[kind])
            + tuple(EXTRAS[n][0] for n in extra))


def feature_names(kind: str, extra: Sequence[str] = ()) -> tuple[str, ...]:
    return tuple(f.name for f in features(kind, extra))


def flux_names(kind: str) -> tuple[str, ...]:
    """The model's flux terms the sensor reads (inputs 3 … 3 + n - 1)."""
    return tuple(n for n, _ in _FLUXES[kind])


def extras_of(kind: str, names: Sequence[str]) -> tuple[str, ...]:
    """The extra features a model with input ``names`` was trained with (those after the
    base list; an unknown name is kept, so that the model check names it)."""
    return tuple(names[len(features(kind)):])


def raw_features(kind: str, x: Mapping[str, np.ndarray], fluxes: Mapping[str, np.ndarray],
                 extra: Sequence[str] = ()) -> np.ndarray:
    """Unfiltered inputs (T, F) from drivers ``x`` (kit columns, arrays) and the no-vent model's
    ``fluxes`` (term name → array). A column that is absent gives NaN (flagged downstream)."""
    n = len(np.asarray(x["t_in"]))
    nan = np.full(n, np.nan)

    def col(name: str) -> np.ndarray:
        v = x.get(name)
        return nan if v is None else np.asarray(v, dtype=float)

    cols = [col("wind"), col("t_in") - col("t_out"), col("rh_in") - col("rh_out")]
    for name, _ in _FLUXES[kind]:
        v = fluxes.get(name)
        cols.append(nan if v is None else np.broadcast_to(np.asarray(v, dtype=float), (n,)))
    cols += [np.broadcast_to(EXTRAS[e][1](col), (n,)) for e in extra]
    return np.column_stack(cols)


def filter_gains(kind: str, step: float = STEP_S, extra: Sequence[str] = ()) -> np.ndarray:
    """Low-pass gains a = 1 - exp(-dt/tau) per feature (1 = unfiltered)."""
    return np.array([1.0 if f.tau <= 0 else -math.expm1(-step / f.tau)
                     for f in features(kind, extra)])


def low_pass(raw: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """Causal first-order low-pass down the rows of ``raw`` (T, F): y_k = y_k-1 + a (x_k - y_k-1).

    A NaN input holds the filter (the row's output is the held value, NaN only before the
    first finite input), exactly as :class:`gateway.vsensor.runtime.VentSensor` does live.
    """
    out = np.full(raw.shape, np.nan)
    state = np.full(raw.shape[1], np.nan)
    a = np.asarray(gains, dtype=float)
    for k, row in enumerate(raw):
        ok = np.isfinite(row)
        fresh = ok & ~np.isfinite(state)
        state = np.where(fresh, row, state)
        upd = ok & ~fresh
        state = np.where(upd, state + a * (row - state), state)
        out[k] = state
    return out


# -- III.32 and the physical range of the flow ---------------------------------------------------
def rho_cp_per_area(gh: Greenhouse) -> float:
    """rho c_p / A [J m-3 K-1 / m2]: III.32's factor from a flow [m3 s-1] to W m-2 per K."""
    return gh.air_density * psy.CP_AIR / gh.floor_area


def heat_loss(flow: np.ndarray | float, dt_in_out: np.ndarray | float, gh: Greenhouse):
    """Ventilation heat loss Q_vent = rho c_p G (T_in - T_out) / A [W m-2] (III.32); positive
    when the house loses heat."""
    return rho_cp_per_area(gh) * np.asarray(flow) * np.asarray(dt_in_out)


def flow_from_heat_loss(q_vent: np.ndarray, dt_in_out: np.ndarray, gh: Greenhouse,
                        min_dt: float = 0.5) -> np.ndarray:
    """III.32 inverted: G = Q_vent A / (rho c_p (T_in - T_out)) [m3 s-1]; NaN where
    |T_in - T_out| < ``min_dt`` [K] (the heat loss says nothing about the flow there)."""
    dt = np.asarray(dt_in_out, dtype=float)
    ok = np.abs(dt) >= min_dt
    return np.where(ok, np.asarray(q_vent) / (rho_cp_per_area(gh) * np.where(ok, dt, 1.0)), np.nan)


@dataclass(frozen=True)
class FlowLimits:
    """The flow's physical range for one greenhouse: the Kittas flow (III.31) through fully open
    vents with the hard upper bounds of C_d and C_w (table 13 box, docs/model-notes.md §3), plus the
    largest leakage the model allows. Lower limit 0: a flow is never negative.

    G_max = C_d sqrt(k_buoy |ΔT| / T_out + C_w k_wind u²) + G_leak, with the drivers' constants
    taken from the model layer (``gateway.model.almeria.kittas_drivers``: B = k_buoy / T_out [K],
    W = k_wind u²)."""

    k_buoy: float  # [m6 s-2] A_eff² 2 g h: III.31's buoyancy coefficient times T_out [K]
    k_wind: float  # [m4] ((A_r + A_s) / 2)²: III.31's wind term per u²
    cd: float
    cw: float
    leak: float  # [m3 s-1]

    def upper(self, dt_in_out: np.ndarray | float, t_out: np.ndarray | float,
              wind: np.ndarray | float) -> np.ndarray:
        """Largest possible flow [m3 s-1] now (a non-finite input gives the no-wind, 30 K value)."""
        dt = _finite(np.abs(np.asarray(dt_in_out, dtype=float)), 30.0)
        tk = _finite(np.asarray(t_out, dtype=float), 0.0) + psy.KELVIN
        u = _finite(np.asarray(wind, dtype=float), 0.0)
        buoy = self.k_buoy * dt / np.maximum(tk, 200.0)
        return self.cd * np.sqrt(buoy + self.k_wind * self.cw * u * u) + self.leak

    def upper_now(self, dt_in_out: float, t_out: float, wind: float) -> float:
        """:meth:`upper` for one step in plain floats (the live path: no numpy call per step)."""
        dt = abs(dt_in_out) if math.isfinite(dt_in_out) else 30.0
        tk = (t_out if math.isfinite(t_out) else 0.0) + psy.KELVIN
        u = wind if math.isfinite(wind) else 0.0
        buoy = self.k_buoy * dt / max(tk, 200.0)
        return self.cd * math.sqrt(buoy + self.k_wind * self.cw * u * u) + self.leak


def _finite(x: np.ndarray, default: float) -> np.ndarray:
    return np.where(np.isfinite(x), x, default)


def flow_limits(gh: Greenhouse, kind: str) -> FlowLimits:
    """Physical flow range of ``gh`` for fluxes of the ``kind`` model."""
    from gateway.model import build_model
    from gateway.model.almeria import kittas_drivers
    from gateway.model.drivers import roof_vent_area, side_vent_area
    from gateway.model.prototype import leakage_flow

    upper = dict(zip(*_names_upper(build_model("almeria", gh), gh), strict=True))
    if kind == "prototype":
        proto = build_model("prototype", gh)
        names, hi = _names_upper(proto, gh)
        leak = leakage_flow(dict(zip(names, hi, strict=True))["c_loss"], gh)
    else:
        leak = upper["c_loss"]
    full = np.array(100.0)
    b, w = kittas_drivers(roof_vent_area(gh.vents, full), side_vent_area(gh.vents, full),
                          gh.vents.height_difference, 0.0, 1.0)  # B at 0 °C, W at 1 m s-1
    return FlowLimits(k_buoy=float(b) * psy.KELVIN, k_wind=float(w), cd=upper["c_ven_d"],
                      cw=upper["c_ven_w"], leak=float(leak))


def _names_upper(model, gh: Greenhouse) -> tuple[list[str], list[float]]:
    return model.names, [float(v) for v in model.bounds(gh)[1]]


def greenhouse_signature(gh: Greenhouse) -> dict[str, float]:
    """What a flow [m3 s-1] depends on besides the measurements: floor, volume, vent openings
    at 100 % and the height between vent centres. Written into the model's metadata; a
    greenhouse that differs by more than :data:`SIGNATURE_TOLERANCE` is flagged."""
    from gateway.model.drivers import roof_vent_area, side_vent_area

    return {
        "floor_area_m2": float(gh.floor_area),
        "volume_m3": float(gh.volume),
        "roof_vent_area_m2": round(float(roof_vent_area(gh.vents, np.array(100.0))), 6),
        "side_vent_area_m2": round(float(side_vent_area(gh.vents, np.array(100.0))), 6),
        "vent_height_m": float(gh.vents.height_difference),
    }


SIGNATURE_TOLERANCE = 0.05
"""Relative difference of a greenhouse's signature above which it counts as another house."""


def signature_mismatch(trained: Mapping[str, float], running: Mapping[str, float]) -> list[str]:
    """Human-readable differences between two signatures (empty: the same house)."""
    out = []
    for key, value in trained.items():
        now = running.get(key)
        if now is None:
            continue
        scale = max(abs(value), abs(now), 1e-9)
        if abs(now - value) / scale > SIGNATURE_TOLERANCE:
            out.append(f"{key} {now:g} (trained on {value:g})")
    return out


def check_names(expected: Sequence[str], found: Sequence[str]) -> str | None:
    """None when equal, else a sentence naming the first difference."""
    expected, found = list(expected), list(found)
    if expected == found:
        return None
    missing = [n for n in expected if n not in found]
    extra = [n for n in found if n not in expected]
    if missing or extra:
        parts = []
        if missing:
            parts.append(f"lacks {', '.join(missing)}")
        if extra:
            parts.append(f"has {', '.join(extra)} the code does not compute")
        return "the model " + " and ".join(parts)
    return f"feature order differs: model {found}, code {expected}"

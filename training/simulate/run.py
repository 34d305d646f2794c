"""``simulate()``: weather + plant + effects → sensor columns (kit CSV) and the truth.

Files written by :meth:`SimResult.write` (``data.csv`` as example):

- ``data.csv``: the kit CSV (docs/data-format.md), measured values through the sensor models.
- ``data.truth.json``: what the sensors cannot see: plant preset and parameters, weather source,
  seed, the injected effects (name, start, params), the sensor calibration errors drawn, and
  the list of arrays in the ``.npz`` with their units.
- ``data.truth.npz``: true series on the CSV's time grid (``time`` as int64 s since the epoch):
  true states, flows [m3 s-1] and heat fluxes [W m-2 of floor]. A state at index k is the value
  at ``time[k]``; a flux at index k is the mean over the interval ending at ``time[k]``
  (index 0 is NaN). Stored as float32.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.kitcsv import write_kit_csv
from gateway.model.psychrometrics import KELVIN
from training.simulate import crop, integrate, sensors
from training.simulate.effects import Effect, PhysicsDrivers, parse_effect
from training.simulate.integrate import FLUXES, R_VAPOUR, State, SubstepInputs
from training.simulate.plant import Plant, get_plant
from training.simulate.weather import DEFAULT_START, Weather, load_weather, parse_start

TRUTH_FORMAT = "serra-sim-truth/1"
SPINUP_DAYS = 1.0
"""The first day of weather is run once before the start, effects off, to settle the soil."""

CONTROL_WIND_WINDOW = 600.0
"""The vent controller sees the wind averaged over this window [s], so gusts do not flap vents."""

STATE_UNITS = {
    "t_air": ("degC", "inside air temperature"),
    "rh_air": ("%", "inside relative humidity"),
    "t_cover": ("degC", "cover temperature"),
    "t_floor": ("degC", "floor/soil surface temperature"),
    "t_deep": ("degC", "deep soil temperature"),
    "c_air": ("kg m-3", "absolute humidity of the inside air"),
    "i_in": ("W m-2", "global radiation under the cover (interval mean)"),
    "lai": ("m2 m-2", "leaf area index"),
    "vent_roof": ("%", "roof vent opening during the interval starting at time[k]"),
    "vent_side": ("%", "side vent opening during the interval starting at time[k]"),
    "t_out": ("degC", "outside air temperature"),
    "rh_out": ("%", "outside relative humidity"),
    "i_glob": ("W m-2", "outside global radiation"),
    "wind": ("m s-1", "outside wind speed"),
    "t_sky": ("degC", "sky temperature"),
    "rain": ("0/1", "rain"),
    "t_sensor_in": ("degC", "inside temperature the sensor reports before noise (with effects)"),
}


@dataclass
class SimResult:
    """A simulation: ``time`` (datetime64[s] UTC), measured ``columns``, and ``truth``.

    ``truth`` holds the metadata written to the JSON and, under ``"series"``, the true arrays
    written to the ``.npz``.
    """

    time: np.ndarray
    columns: dict[str, np.ndarray]
    truth: dict = field(default_factory=dict)

    @property
    def series(self) -> dict[str, np.ndarray]:
        """True series by name (see ``truth["units"]``)."""
        return self.truth["series"]

    def write(self, csv_path: str | Path) -> tuple[Path, Path, Path]:
        """Write the kit CSV, ``<stem>.truth.json`` and ``<stem>.truth.npz`` beside it."""
        csv_path = Path(csv_path)
        write_kit_csv(csv_path, self.time, self.columns)
        stem = csv_path.with_suffix("")
        json_path = stem.with_name(stem.name + ".truth.json")
        npz_path = stem.with_name(stem.name + ".truth.npz")
        meta = {k: v for k, v in self.truth.items() if k != "series"}
        meta["csv"] = csv_path.name
        meta["arrays"] = npz_path.name
        json_path.write_text(json.dumps(meta, indent=1, default=_json_default) + "\n",
                             encoding="utf-8")
        arrays = {"time": self.time.astype("datetime64[s]").astype(np.int64)}
        # float32 halves the file; the in-memory truth stays float64 (balances are tested there).
        arrays.update({k: np.asarray(v, dtype=np.float32) for k, v in self.series.items()})
        np.savez_compressed(npz_path, **arrays)
        return csv_path, json_path, npz_path


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def load_truth(json_path: str | Path) -> dict:
    """Read a truth JSON and its ``.npz``; the arrays come back under ``"series"``."""
    json_path = Path(json_path)
    meta = json.loads(json_path.read_text(encoding="utf-8"))
    with np.load(json_path.with_name(meta["arrays"])) as data:
        series = {k: data[k] for k in data.files}
    meta["time"] = series.pop("time").astype("datetime64[s]")
    meta["series"] = series
    return meta


def _as_effects(effects: Iterable[Effect | str], start: np.datetime64) -> list[Effect]:
    out = []
    for e in effects:
        e = parse_effect(e, start) if isinstance(e, str) else e
        if e is not None:
            out.append(e)
    return out


def _substep_inputs(plant: Plant, weather: Weather, substeps: int, t_ground: float,
                    lai_days0: float) -> SubstepInputs:
    sec = weather.seconds()
    step = sec[1] - sec[0]
    mid = (sec[0] + (np.arange((len(sec) - 1) * substeps) + 0.5) * step / substeps)

    def at(x: np.ndarray) -> np.ndarray:
        return np.interp(mid, sec, x)

    c_out = integrate.vapour_concentration(weather.t_out, weather.rh_out)
    storm = np.zeros(len(sec), dtype=bool)
    if plant.controller is not None:
        storm = plant.controller.storm(_trailing_mean(weather.wind, CONTROL_WIND_WINDOW / step))
    days = lai_days0 + (mid - sec[0]) / 86400.0
    return SubstepInputs(
        t_out=at(weather.t_out), c_out=at(c_out), i_glob=at(weather.i_glob),
        wind=at(weather.wind), t_sky=at(weather.t_sky),
        lai=crop.logistic_lai(days, plant.lai_start, plant.lai_max, plant.lai_rate),
        t_ground=t_ground, storm_out=storm, rain_out=weather.rain, time_out=sec,
    )


def _trailing_mean(x: np.ndarray, n: float) -> np.ndarray:
    """Mean of the last ``n`` samples (fewer at the start), as a climate computer filters wind."""
    n = max(int(round(n)), 1)
    c = np.cumsum(np.concatenate([[0.0], x]))
    lo = np.maximum(np.arange(1, len(x) + 1) - n, 0)
    return (c[1:] - c[lo]) / (np.arange(1, len(x) + 1) - lo)


def _drivers(effects: list[Effect], weather: Weather, substeps: int, volume: float
             ) -> PhysicsDrivers:
    sec = weather.seconds()
    step = sec[1] - sec[0]
    n_sub = (len(sec) - 1) * substeps
    mid = sec[0] + (np.arange(n_sub) + 0.5) * step / substeps
    drivers = PhysicsDrivers.neutral(n_sub)
    for e in effects:
        if e.kind == "physics":
            start = float(np.datetime64(e.start, "s").astype(np.int64))
            e.apply_physics(drivers, mid >= start, volume)
    return drivers


def _spin_up(p: Plant, wx: Weather, substeps: int, t_ground: float, step: float
             ) -> tuple[State, float, float]:
    """The state and vent positions after the first day (effects off), so the soil and cover
    start consistent."""
    n_spin = min(len(wx), int(round(SPINUP_DAYS * 86400.0 / step)) + 1)
    spin = Weather(*(getattr(wx, f)[:n_spin] for f in
                     ("time", "t_out", "rh_out", "i_glob", "wind", "t_sky", "rain")),
                   source=wx.source, latitude=wx.latitude)
    c0 = float(integrate.vapour_concentration(wx.t_out[0], wx.rh_out[0]))
    state = State(wx.t_out[0], wx.t_out[0], wx.t_out[0] + 1.0, t_ground, c0)
    traj = integrate.run(p, _substep_inputs(p, spin, substeps, t_ground, 0.0),
                         PhysicsDrivers.neutral((n_spin - 1) * substeps), state, step, substeps)
    state = State(traj.t_a[-1], traj.t_c[-1], traj.t_f[-1], traj.t_d[-1], traj.c_a[-1])
    return state, traj.vent_roof[-1], traj.vent_side[-1]


def simulate(
    plant: str | Plant = "almeria",
    weather: str | Weather = "bleiswijk",
    start: str | np.datetime64 | None = None,
    days: float = 14.0,
    effects: Iterable[Effect | str] = (),
    seed: int = 0,
    step: float = 60.0,
    substeps: int = 2,
) -> SimResult:
    """Simulate ``days`` [d] of a greenhouse from ``start`` (UTC) every ``step`` [s].

    ``plant``: preset name ('prototype', 'almeria') or a :class:`Plant`. ``weather``: 'bleiswijk'
    (measured, 2009-10-20..2009-12-10), 'biskra' or 'almeria' (synthetic, seeded), or a
    :class:`Weather` already on the output grid. ``effects``: :class:`Effect` objects or spec
    strings (see :mod:`training.simulate.effects`). ``seed`` drives synthetic weather and sensor
    errors. ``substeps`` implicit integration sub-steps per output step.
    """
    p = get_plant(plant)
    if isinstance(weather, Weather):
        wx = weather
    else:
        t0 = parse_start(start if start is not None else DEFAULT_START.get(weather, "2009-11-01"))
        wx = load_weather(weather, t0, days, step, seed)
    t0 = wx.time[0]
    step = float(wx.seconds()[1] - wx.seconds()[0])
    effect_list = _as_effects(effects, t0)
    t_ground = float(np.mean(wx.t_out)) + p.ground_offset

    state, roof0, side0 = _spin_up(p, wx, substeps, t_ground, step)
    inputs = _substep_inputs(p, wx, substeps, t_ground, 0.0)
    traj = integrate.run(p, inputs, _drivers(effect_list, wx, substeps, p.volume), state, step,
                         substeps, roof0, side0)

    fluxes = integrate.interval_means(traj.fluxes, substeps)
    i_in = integrate.interval_means(traj.i_in, substeps)
    rh_air = 100.0 * traj.c_a * R_VAPOUR * (traj.t_a + KELVIN) / (
        610.78 * np.exp(17.2694 * traj.t_a / (traj.t_a + 237.3)))
    sec = wx.seconds()
    lai = crop.logistic_lai((sec - sec[0]) / 86400.0, p.lai_start, p.lai_max, p.lai_rate)
    series = {
        "t_air": traj.t_a, "rh_air": rh_air, "t_cover": traj.t_c, "t_floor": traj.t_f,
        "t_deep": traj.t_d, "c_air": traj.c_a, "i_in": i_in, "lai": lai,
        "vent_roof": traj.vent_roof, "vent_side": traj.vent_side,
        "t_out": wx.t_out, "rh_out": wx.rh_out, "i_glob": wx.i_glob, "wind": wx.wind,
        "t_sky": wx.t_sky, "rain": wx.rain,
    }
    series.update({name: fluxes[:, i] for i, (name, _, _) in enumerate(FLUXES)})

    columns, calibration = _measure(p, wx, series, effect_list, seed)
    units = {k: {"unit": u, "meaning": m} for k, (u, m) in STATE_UNITS.items()}
    units.update({n: {"unit": u, "meaning": m} for n, u, m in FLUXES})
    truth = {
        "format": TRUTH_FORMAT,
        "plant": p.name,
        "plant_params": p.to_dict(),
        "weather": wx.source,
        "weather_notes": wx.notes,
        "start": str(t0) + "Z",
        "end": str(wx.time[-1]) + "Z",
        "step_s": step,
        "substeps": substeps,
        "seed": int(seed),
        "t_ground": t_ground,
        "effects": [e.to_dict() for e in effect_list],
        "sensors": calibration,
        "units": units,
        "series": series,
    }
    return SimResult(time=wx.time.copy(), columns=columns, truth=truth)


def _measure(p: Plant, wx: Weather, series: dict[str, np.ndarray], effects: list[Effect],
             seed: int) -> tuple[dict[str, np.ndarray], dict]:
    """Sensor readings of every column the plant measures, and the calibrations drawn."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 104729]))
    specs = sensors.sensor_set(p.measured)
    cal = {name: sensors.draw_calibration(spec, rng) for name, spec in specs.items()}
    sec = wx.seconds()
    i_in = np.nan_to_num(series["i_in"], nan=float(series["i_in"][1]) if len(sec) > 1 else 0.0)

    # Inside sensor: its body may be sun-heated (also lowers its RH), its reading may drift.
    body = np.zeros(len(sec))
    offset = np.zeros(len(sec))
    for e in effects:
        if e.kind != "sensor":
            continue
        start = float(np.datetime64(e.start, "s").astype(np.int64))
        active = sec >= start
        days = np.maximum(sec - start, 0.0) / 86400.0
        body = body + np.where(active, e.sensor_body_offset(i_in, days), 0.0)
        offset = offset + np.where(active, e.sensor_reading_offset(i_in, days), 0.0)
    t_body = series["t_air"] + body
    rh_body = np.minimum(series["rh_air"] * _psat(series["t_air"]) / _psat(t_body), 100.0)
    series["t_sensor_in"] = t_body + offset

    true = {
        "t_in": t_body + offset, "rh_in": rh_body, "t_out": wx.t_out, "rh_out": wx.rh_out,
        "i_glob": wx.i_glob, "wind": wx.wind, "rain": wx.rain, "i_in": i_in,
        "t_soil": series["t_floor"], "vent_roof": series["vent_roof"],
        "vent_side": series["vent_side"], "lai": series["lai"],
    }
    columns = {}
    for name, spec in specs.items():
        columns[name] = sensors.measure(true[name], spec, cal[name], rng)
    # A failed DHT22/HC2S3 read loses temperature and humidity together.
    for t_col, rh_col in (("t_in", "rh_in"), ("t_out", "rh_out")):
        if t_col in columns and rh_col in columns:
            columns[rh_col][np.isnan(columns[t_col])] = np.nan
    return columns, {name: c.to_dict() for name, c in cal.items()}


def _psat(t: np.ndarray) -> np.ndarray:
    return 610.78 * np.exp(17.2694 * t / (t + 237.3))

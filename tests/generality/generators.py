"""The generality suite's generators behind one call: 14 days of kit-sensor data (t_in, rh_in,
t_out, rh_out, i_glob, wind at 5-minute rows) of a greenhouse on a weather window, with at most
one undeclared change from day 6.4.

- ``refsim``: the reference simulator (training/simulate), its Almería house (877 m2, vents
  under a roof-then-side controller) with the kit's sensors.
- ``twonode``: tests/twonode.py's two-node house (877 m2, proportional vents).
- ``vanthoor``: tests/generality/vanthoor.py, a reduced Vanthoor (2011) model of a 4-ha Venlo
  glasshouse. **Held out**: declared before any tuning; nothing is tuned on it (the engineer
  tuning the diagnosis never sees it), and it is reported apart.

Change kinds, the same physical meaning in each generator (each generator's own physics):
``transmission`` (cover × 0.7), ``ventilation`` (more air exchange), ``heater`` (25 W m-2),
``night_heater`` (25 W m-2 while dark), ``thermal_mass`` (water added), ``sun_sensor`` (inside
sensor heated by the sun, 0.006 K per W m-2 inside), ``drift`` (0.5 K d-1); outside the
diagnosis library: ``misting`` (evaporative cooling at midday) and ``controller`` (another vent
controller). The two-node house alone has ``thermostat`` (the air heated to a setpoint: a
heated house, tests/generality/heated_study.py, which runs it from ``change_day=0``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from gateway.greenhouse import Greenhouse, parse_greenhouse
from tests.generality import kit_sensors, vanthoor
from tests.generality.windows import Window
from training.simulate import simulate
from training.simulate.control import VentController
from training.simulate.effects import Effect, PhysicsDrivers
from training.simulate.plant import KIT_COLUMNS, get_plant

GENERATORS = ("refsim", "twonode", "vanthoor")
HELD_OUT = ("vanthoor",)
KINDS = ("transmission", "ventilation", "heater", "night_heater", "thermal_mass", "sun_sensor",
         "drift")
OUTSIDE = ("misting", "controller")
TWONODE_ONLY = ("thermostat",)
"""Changes only the two-node house has (TWONODE_SPECS): not in the suite's table."""
EXPECTED = {
    "transmission": {"solar_gain_change"},
    "ventilation": {"extra_ventilation"},
    "heater": {"heat_source", "night_heat_source"},
    "night_heater": {"heat_source", "night_heat_source"},
    "thermal_mass": {"thermal_mass", "heat_store_added"},
    "sun_sensor": {"sensor_radiation_bias"},
    "drift": {"sensor_drift"},
}
"""Change kind → library effect(s) that name it (docs/effects.md, documented equivalents)."""
CHANGE_DAY = 6.4
KIT = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind")
ROW_S = 300.0
GEOMETRY = {"refsim": (877.0, 877.0 * 3.5), "twonode": (877.0, 877.0 * 3.5),
            "vanthoor": (4e4, 4e4 * 4.2)}
"""(floor area [m2], volume [m3]) each generator's house has: the greenhouse file a user would
write for it."""


@dataclass
class KitData:
    """One generated dataset: kit columns on ``time`` (5-min rows) and what was injected."""

    time: np.ndarray
    columns: dict[str, np.ndarray]
    generator: str
    window: Window
    kind: str  # "none", a KINDS or OUTSIDE entry
    start: np.datetime64 | None
    size: str
    truth: dict = field(default_factory=dict)

    def greenhouse(self) -> Greenhouse:
        floor, volume = GEOMETRY[self.generator]
        return parse_greenhouse({
            "name": f"{self.generator}-{self.window.name}",
            "geometry": {"floor_area": floor, "volume": volume},
            "site": {"latitude": self.window.latitude, "longitude": self.window.longitude},
        }, f"<generality {self.generator}>")

    def write_csv(self, path) -> None:
        from gateway.kitcsv import write_kit_csv

        write_kit_csv(path, self.time, self.columns)


def generate(generator: str, window: Window, kind: str = "none", seed: int = 1,
             change_day: float = CHANGE_DAY, amount: float | None = None,
             row_s: float = ROW_S) -> KitData:
    """Kit data of ``generator`` on ``window`` with the change ``kind`` from ``change_day`` [d]
    (0: from the first sample). ``amount``: the two-node house's size of the change in its own
    unit instead of TWONODE_SPECS' (the ``thermostat`` setpoint [°C]); the other generators
    take their sizes as they are. ``row_s``: the logger's row interval [s], a multiple of the
    simulators' 60-s readings (every k-th reading: the kit's instantaneous samples; the
    held-out generator has its 5-minute rows only)."""
    if generator not in GENERATORS:
        raise ValueError(f"unknown generator {generator!r} (known: {', '.join(GENERATORS)})")
    known = KINDS + OUTSIDE + (TWONODE_ONLY if generator == "twonode" else ())
    if kind != "none" and kind not in known:
        raise ValueError(f"unknown change {kind!r} for {generator} (known: {', '.join(known)})")
    if amount is not None and (generator != "twonode" or kind == "none"):
        raise ValueError("amount sizes a two-node house's change only")
    every = int(round(row_s / 60.0))
    if every < 1 or every * 60.0 != row_s or (generator == "vanthoor" and row_s != ROW_S):
        raise ValueError(f"row interval {row_s:g} s: not a multiple of 60 s (vanthoor: {ROW_S:g} s)")
    start = None if kind == "none" else window.at_day(change_day)
    if generator == "twonode":
        time, cols, size = _twonode(window, kind, start, seed, amount, every)
    elif generator == "refsim":
        time, cols, size = _refsim(window, kind, start, seed, every)
    else:
        time, cols, size = _vanthoor(window, kind, start, seed)
    return KitData(time, cols, generator, window, kind, start, size)


# -- the reference simulator ---------------------------------------------------------------------
REFSIM_SPECS = {"transmission": "cover_transmission:factor=0.7", "ventilation": "extra_leakage:ach=4",
                "heater": "heater:power=25", "night_heater": "heater:power=25,night_only=1",
                "thermal_mass": "thermal_mass:factor=3", "sun_sensor": "sensor_radiation_bias:k=0.006",
                "drift": "sensor_drift:rate=0.5"}
MIST_W = 60.0  # refsim misting: sensible cooling [W m-2], 11-15 h solar time


@dataclass(frozen=True)
class Misting(Effect):
    """Evaporative cooling bursts in the simulator's heater slot (a negative power) from 11 to
    15 h solar time; ``hours`` is the solar hour of each simulator sub-step."""

    name: ClassVar[str] = "misting"
    hours: tuple = ()

    def apply_physics(self, drivers: PhysicsDrivers, active: np.ndarray, volume: float) -> None:
        hours = np.asarray(self.hours)
        burst = active & (hours >= 11.0) & (hours < 15.0)
        drivers.heaters.append((burst, -MIST_W, float("nan"), False))


@dataclass(frozen=True)
class CappedVents(VentController):
    """Another grower's controller: openings capped at ``wind_cap`` [%] from sample
    ``from_index`` of the run on (the simulator's storm rule, switched on for good)."""

    from_index: int = 0
    length: int = 0

    def storm(self, wind: np.ndarray) -> np.ndarray:
        out = super().storm(wind)
        if len(wind) == self.length:  # the run itself, not the spin-up day
            out[self.from_index:] = True
        return out


def _refsim(window: Window, kind: str, start, seed: int, every: int = int(ROW_S // 60)):
    plant = get_plant("almeria").with_(measured=KIT_COLUMNS)
    weather = window.sim_weather()
    effects: list = []
    size = ""
    if kind in REFSIM_SPECS:
        name, _, params = REFSIM_SPECS[kind].partition(":")
        effects = [f"{name}@{start}:{params}"]
        size = REFSIM_SPECS[kind]
    elif kind == "misting":
        effects = [Misting(start=start, hours=tuple(_solar_hours(window, substeps=2)))]
        size = f"{MIST_W:g} W m-2 evaporative cooling 11-15 h solar time (its vapour not added)"
    elif kind == "controller":
        plant = plant.with_(controller=CappedVents(
            from_index=int(np.searchsorted(weather.time, start)), length=len(weather.time),
            wind_cap=10.0))
        size = "vents capped at 10 % (roof and side)"
    r = simulate(plant=plant, weather=weather, effects=effects, seed=seed)
    rows = np.arange(0, len(r.time), every)
    return r.time[rows], {c: r.columns[c][rows] for c in KIT}, size


def _solar_hours(window: Window, substeps: int) -> np.ndarray:
    """Solar hour of day at the simulator's sub-step midpoints (refsim misting schedule)."""
    sec = (window.time - window.time[0]).astype("timedelta64[s]").astype(float)
    step = sec[1] - sec[0]
    mid = sec[0] + (np.arange((len(sec) - 1) * substeps) + 0.5) * step / substeps
    day0 = (window.time[0] - window.time[0].astype("datetime64[D]")).astype("timedelta64[s]")
    return ((mid + day0.astype(float)) / 3600.0 + window.longitude / 15.0) % 24.0


# -- the two-node house ----------------------------------------------------------------------------
TWONODE_SPECS = {"transmission": ("whitening", 0.7), "ventilation": ("door", 4.0),
                 "heater": ("heater", 25.0), "night_heater": ("nightheater", 25.0),
                 "thermal_mass": ("barrels", 20e3), "sun_sensor": ("sunsensor", 0.006),
                 "drift": ("drift", 0.5), "misting": ("misting", 60.0),
                 "controller": ("controller", 0.0), "thermostat": ("thermostat", 12.0)}
"""Change kind → (tests/twonode.py's effect, its size): the thermostat's is a setpoint [°C]."""


def _twonode(window: Window, kind: str, start, seed: int, amount: float | None = None,
             every: int = int(ROW_S // 60)):
    from tests import twonode

    effect, amp = TWONODE_SPECS.get(kind, (None, None))
    if amount is not None:
        amp = amount
    at = None if start is None else str(start)
    w, rec, on, tsec, _, _ = twonode.simulate("house", None, None, effect, at, amp, seed,
                                              weather=window.twonode_weather(),
                                              site=(window.latitude, window.longitude))
    tau_at = None if at is None else float((start - w["time"][0]).astype("timedelta64[s]").astype(float))
    cols = twonode.sensors("house", w, rec, on, tsec, effect, amp, tau_at, seed)
    rows = np.arange(0, len(tsec), every)
    size = "" if effect is None else f"{effect} amp={amp:g}"
    return w["time"][rows], {c: np.asarray(cols[c], float)[rows] for c in KIT}, size


# -- the held-out glasshouse ------------------------------------------------------------------------
VANTHOOR_SIZES = {"transmission": ("whitening", 0.7), "ventilation": ("leakage", 3.0),
                  "heater": ("heater", 25.0), "night_heater": ("night_heater", 25.0),
                  "thermal_mass": ("thermal_mass", 40.0), "sun_sensor": ("sun_sensor", 0.006),
                  "drift": ("drift", 0.5), "misting": ("misting", 2e-5),
                  "controller": ("controller", 0.0)}


def _vanthoor(window: Window, kind: str, start, seed: int):
    change = None
    size = ""
    if kind != "none":
        name, amount = VANTHOOR_SIZES[kind]
        change = vanthoor.Change(name, start, amount)
        size = f"{name} {amount:g}"
    run = vanthoor.Glasshouse(vanthoor.Venlo(), window, change).run()
    drift = None
    if change is not None and change.kind == "drift":
        days = (window.time - start).astype("timedelta64[s]").astype(float) / 86400.0
        drift = np.where(days >= 0, change.amount * days, 0.0)
    cols = kit_sensors.kit_columns(run.t_body, run.vp_air, window, seed, drift)
    return window.time[::kit_sensors.ROW], cols, size

"""Kit-sensor test data for the diagnosis study (issue 10): two generators × weather windows.

Each case is 14 days of kit readings (t_in, rh_in, t_out, rh_out, i_glob, wind) at 5-minute
rows, with one undeclared change from day ``START_DAY`` (or none), and a greenhouse description
whose ``[site]`` is where the weather was made. Generators:

- ``refsim``: the reference simulator (training/simulate), driven by the window's weather
  (``Window.sim_weather``); its sky is the weather file's measured one.
- ``twonode``: the independent two-node generator (tests/twonode.py), driven by the window's
  weather and site.

Plants: ``box`` (the kit's nursery box: refsim ``prototype``, twonode ``box``) and ``house``
(an 877 m2 vented house: refsim ``almeria``, twonode ``house``), both diagnosed with kit
sensors only. Effect kinds (the library names that count as naming them in ``EXPECTED``):
``solar`` (cover whitened), ``ventilation`` (door / extra leakage), ``heat`` (heater),
``mass`` (water added as thermal mass), ``sun_sensor`` (sun-heated inside sensor), ``drift``
(drifting sensor); plus ``none`` and ``misting`` (a change outside the library).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse, load_greenhouse
from gateway.kitcsv import write_kit_csv
from gateway.series import Series, load_series
from tests.generality.windows import Window

KIT = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind")
STEP = 300.0
"""Rows of the data the diagnosis reads [s] (generators run at 60 s, block-averaged)."""
START_DAY = 6.43
"""The undeclared change starts 6 d 10 h 20 min into the window."""
KINDS = ("solar", "ventilation", "heat", "mass", "sun_sensor", "drift")
EXPECTED = {
    "solar": {"solar_gain_change"},
    "ventilation": {"extra_ventilation"},
    "heat": {"heat_source", "night_heat_source"},
    "mass": {"thermal_mass", "heat_store_added"},
    "sun_sensor": {"sensor_radiation_bias"},
    "drift": {"sensor_drift"},
}
"""Effect kind → library effects that count as naming it."""
PRESET = {"box": "biskra-prototype", "house": "almeria-palmerillas"}

REFSIM = {
    "box": {"solar": "cover_transmission:factor=0.6", "ventilation": "extra_leakage:ach=30",
            "heat": "heater:power=25", "mass": "thermal_mass:factor=10",
            "sun_sensor": "sensor_radiation_bias:k=0.006", "drift": "sensor_drift:rate=0.5"},
    "house": {"solar": "cover_transmission:factor=0.6", "ventilation": "extra_leakage:ach=4",
              "heat": "heater:power=25", "mass": "thermal_mass:factor=3",
              "sun_sensor": "sensor_radiation_bias:k=0.006", "drift": "sensor_drift:rate=0.5"},
}
"""Reference-simulator effect specs (training/simulate/effects.py) per plant."""
TWONODE = {
    "box": {"solar": ("whitening", 0.6), "ventilation": ("door", 25.0), "heat": ("heater", 25.0),
            "mass": ("barrels", 40e3), "sun_sensor": ("sunsensor", 0.006),
            "drift": ("drift", 0.5)},
    "house": {"solar": ("whitening", 0.6), "ventilation": ("door", 4.0),
              "heat": ("nightheater", 30.0), "mass": ("barrels", 20e3),
              "sun_sensor": ("sunsensor", 0.006), "drift": ("drift", 0.5)},
}
"""Two-node generator effects (tests/twonode.py) per plant: (name, amplitude)."""


@dataclass
class Case:
    generator: str
    plant: str
    window: str
    kind: str  # one of KINDS, "none" or "misting"
    start: np.datetime64 | None  # truth (None: no change)
    series: Series
    gh: Greenhouse


def greenhouse_toml(plant: str, window: Window) -> str:
    """The plant's preset with the window's ``[site]`` and kit sensors only."""
    import tomllib

    raw = tomllib.loads(Path(load_greenhouse(PRESET[plant]).source).read_text(encoding="utf-8"))
    raw["sensors"] = list(KIT)
    raw["site"] = {"latitude": window.latitude, "longitude": window.longitude}

    def value(v) -> str:
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {value(v)}" for k, v in raw.items() if not isinstance(v, dict)]
    for k, table in raw.items():
        if isinstance(table, dict):
            lines += ["", f"[{k}]"] + [f"{q} = {value(v)}" for q, v in table.items()]
    return "\n".join(lines) + "\n"


def misting(time: np.ndarray, t_in: np.ndarray, start: np.datetime64) -> np.ndarray:
    """Misting bursts at 11:00 and 15:00 UTC from ``start``: each cools the air by 2.5 K and
    relaxes with a 20-minute time constant (a change no library effect describes)."""
    t = time.astype("datetime64[m]").astype(np.int64)
    minute = t % 1440
    s = np.datetime64(start, "m").astype(np.int64)
    pulse = np.zeros(len(t))
    for clock in (11 * 60, 15 * 60):
        since = (minute - clock) % 1440
        pulse += np.where((since < 120) & (t >= s), -2.5 * np.exp(-since / 20.0), 0.0)
    return np.round(t_in + pulse, 1)


def _refsim(plant: str, window: Window, kind: str, start: np.datetime64, seed: int):
    from training.simulate import simulate

    name = "prototype" if plant == "box" else "almeria"
    effects = []
    if kind in KINDS:
        eff, params = REFSIM[plant][kind].split(":")
        effects = [f"{eff}@{str(start)}:{params}"]
    r = simulate(plant=name, weather=window.sim_weather(), effects=effects, seed=seed)
    return r.time, {c: np.asarray(r.columns[c], dtype=float) for c in KIT}


def _twonode(plant: str, window: Window, kind: str, start: np.datetime64, seed: int):
    from tests import twonode

    effect, amp = TWONODE[plant][kind] if kind in KINDS else (None, None)
    at = str(start) if effect else None
    w, rec, on, tsec, _, _ = twonode.simulate(plant, None, None, effect, at, amp, seed,
                                              weather=window.twonode_weather(),
                                              site=(window.latitude, window.longitude))
    tau = None if at is None else float((np.datetime64(at, "s") - w["time"][0]).astype(float))
    cols = twonode.sensors(plant, w, rec, on, tsec, effect, amp, tau, seed)
    return w["time"], {c: np.asarray(cols[c], dtype=float) for c in KIT}


def make_case(generator: str, plant: str, window: Window, kind: str, seed: int = 1,
              start_day: float = START_DAY, workdir: str | Path | None = None) -> Case:
    """Simulate one case and read it back as the tools would (kit CSV → 5-minute series)."""
    if generator not in ("refsim", "twonode"):
        raise ValueError(f"unknown generator {generator!r}")
    start = window.at_day(start_day)
    make = _refsim if generator == "refsim" else _twonode
    time, cols = make(plant, window, "none" if kind == "misting" else kind, start, seed)
    if kind == "misting":
        cols["t_in"] = misting(time, cols["t_in"], start)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        csv = Path(tmp) / "data.csv"
        write_kit_csv(csv, time, cols)
        series = load_series(str(csv), step=STEP)
        toml = Path(tmp) / "greenhouse.toml"
        toml.write_text(greenhouse_toml(plant, window), encoding="utf-8")
        gh = load_greenhouse(toml)
    return Case(generator, plant, window.name, kind, None if kind == "none" else start,
                series, gh)


def _summer_from(start: str):
    from dataclasses import replace

    from tests.generality.windows import bleiswijk_window, summer

    return lambda: replace(summer(bleiswijk_window(start, 14.0)), name=f"summer-from-{start[5:10]}")


def _bleiswijk(start: str):
    from tests.generality.windows import bleiswijk_window

    return lambda: bleiswijk_window(start, 14.0, f"bleiswijk-{start[5:10]}")


EFFECT_FREE_WINDOWS = {
    "autumn": lambda: _window("autumn"),
    "winter": lambda: _window("winter"),
    "summer": lambda: _window("summer"),
    "bleiswijk-10-27": _bleiswijk("2009-10-27T00:00"),
    "bleiswijk-11-03": _bleiswijk("2009-11-03T00:00"),
    "bleiswijk-11-10": _bleiswijk("2009-11-10T00:00"),
    "bleiswijk-11-17": _bleiswijk("2009-11-17T00:00"),
    "summer-from-10-27": _summer_from("2009-10-27T00:00"),
    "summer-from-11-03": _summer_from("2009-11-03T00:00"),
    "summer-from-11-17": _summer_from("2009-11-17T00:00"),
}
"""Ten 14-day windows for the effect-free runs: the three study windows, four more Bleiswijk
stretches (the file holds 51 days) and three more Mediterranean summers made from them."""


def _window(name: str) -> Window:
    from tests.generality.windows import load_window

    return load_window(name)

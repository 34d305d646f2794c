"""Greenhouse description: geometry, vents, crop and sensors, read from TOML.

Built-in presets live in ``gateway/presets/<name>.toml``; a user's own file works the same way.
Unknown keys and impossible values are errors that name the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.tomlfile import read_toml

PRESET_DIR = Path(__file__).parent / "presets"


class GreenhouseError(ValueError):
    """A greenhouse description that cannot be used; the message names the key."""


@dataclass(frozen=True)
class Vents:
    """Natural-ventilation openings (thesis III.33–III.34)."""

    roof_count: int = 0  # [-] number of roof flaps
    roof_length: float = 0.0  # [m]
    roof_width: float = 0.0  # [m] flap width (hinge to edge)
    roof_max_angle: float = 45.0  # [deg] flap angle at 100 % opening
    side_count: int = 0  # [-]
    side_length: float = 0.0  # [m]
    side_height: float = 0.0  # [m]
    height_difference: float = 0.0  # [m] between roof and side vent centres


@dataclass(frozen=True)
class Crop:
    lai: float = 0.0  # [m2 m-2] leaf area index used when the data has no lai column
    extinction: float = 0.64  # [-] short-wave extinction coefficient (tomato)


@dataclass(frozen=True)
class Site:
    """Where the greenhouse stands: the sun's position and the clear sky follow from it
    (gateway/model/solar.py)."""

    latitude: float  # [deg] north positive
    longitude: float  # [deg] east positive
    elevation: float = 0.0  # [m] above sea level


@dataclass(frozen=True)
class Greenhouse:
    """Static description of one greenhouse (SI units)."""

    name: str
    floor_area: float  # [m2]
    volume: float  # [m3]
    air_density: float = 1.205  # [kg m-3] table 2 (gamma_0)
    pressure: float = 101.0  # [kPa] table 2
    cover_transmission: float = 0.7  # [-] c_tsw when no inside radiation is measured
    vents: Vents = field(default_factory=Vents)
    crop: Crop = field(default_factory=Crop)
    site: Site | None = None
    """``[site]``; None when the file gives none (then nothing that needs the sun's position
    can run, and the tools say so)."""
    sensors: tuple[str, ...] = ()
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    source: str = "<memory>"
    online: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Online estimator overrides per output (``[online.t_in]``, ``[online.i_in]``): window,
    every, iterations, bats, prior (docs/online-estimator.md)."""

    @property
    def mean_height(self) -> float:
        """Volume over floor area [m]."""
        return self.volume / self.floor_area


_SCHEMA: dict[str, dict[str, tuple[type, float, float]]] = {
    "geometry": {
        "floor_area": (float, 1e-3, 1e6),
        "volume": (float, 1e-3, 1e7),
    },
    "air": {"density": (float, 0.5, 2.0), "pressure": (float, 50.0, 110.0)},
    "cover": {"transmission": (float, 0.0, 1.0)},
    "vents": {
        "roof_count": (int, 0, 1000),
        "roof_length": (float, 0.0, 1000.0),
        "roof_width": (float, 0.0, 100.0),
        "roof_max_angle": (float, 0.0, 180.0),
        "side_count": (int, 0, 1000),
        "side_length": (float, 0.0, 1000.0),
        "side_height": (float, 0.0, 100.0),
        "height_difference": (float, 0.0, 100.0),
    },
    "crop": {"lai": (float, 0.0, 15.0), "extinction": (float, 0.0, 3.0)},
    "site": {
        "latitude": (float, -90.0, 90.0),
        "longitude": (float, -180.0, 180.0),
        "elevation": (float, -500.0, 9000.0),
    },
}
MEAN_HEIGHT = (0.1, 50.0)
"""[m] volume over floor area a greenhouse can have: a cold frame to a botanical garden's dome.
Each key alone may be in range while the two disagree by a unit (0.68 m2 written 6800, cm2)."""
_TOP = {"name", "description", "sensors", "parameters", "online", *_SCHEMA}
_PARAM_KEYS = {"value", "bounds", "variation"}
ONLINE_OUTPUTS = ("t_in", "i_in")
_ONLINE_KEYS: dict[str, tuple[type, float, float]] = {
    "window": (int, 1, 10000),  # n past samples re-simulated
    "every": (int, 1, 10000),  # period in model steps
    "iterations": (int, 1, 100000),  # RSBA iterations per estimation
    "bats": (int, 2, 10000),  # RSBA population
    "prior": (float, 0.0, 1e6),  # weight of the pull toward the starting values [°C²]
}


def list_presets() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def load_greenhouse(spec: str | Path) -> Greenhouse:
    """A preset name (``biskra-prototype``, ``almeria-palmerillas``) or a path to a TOML file."""
    path = Path(spec)
    if not path.suffix and (PRESET_DIR / f"{spec}.toml").exists():
        path = PRESET_DIR / f"{spec}.toml"
    elif not path.exists():
        raise GreenhouseError(
            f"{spec}: no such file, and not a preset (presets: {', '.join(list_presets())})"
        )
    return parse_greenhouse(read_toml(path, GreenhouseError, "greenhouse file"), str(path))


def parse_greenhouse(raw: dict[str, Any], source: str = "<memory>") -> Greenhouse:
    """Validate a TOML document (as a dict) into a Greenhouse."""
    for key in raw:
        if key not in _TOP:
            raise GreenhouseError(f"{source}: unknown key '{key}' (allowed: {', '.join(sorted(_TOP))})")
    if "geometry" not in raw:
        raise GreenhouseError(f"{source}: missing [geometry] with floor_area and volume")
    sections: dict[str, dict[str, Any]] = {}
    for section, fields in _SCHEMA.items():
        table = raw.get(section, {})
        if not isinstance(table, dict):
            raise GreenhouseError(f"{source}: '{section}' must be a table")
        out = {}
        for key, value in table.items():
            if key not in fields:
                raise GreenhouseError(
                    f"{source}: unknown key '{section}.{key}' (allowed: {', '.join(fields)})"
                )
            kind, lo, hi = fields[key]
            out[key] = _check_number(source, f"{section}.{key}", value, kind, lo, hi)
        sections[section] = out
    geometry = sections["geometry"]
    _check_geometry(geometry, source)
    sensors = raw.get("sensors", [])
    if not isinstance(sensors, list) or not all(isinstance(s, str) for s in sensors):
        raise GreenhouseError(f"{source}: 'sensors' must be a list of kit column names")
    from gateway.kitcsv import COLUMNS

    for s in sensors:
        if s not in COLUMNS:
            raise GreenhouseError(f"{source}: 'sensors' names unknown column '{s}'")
    params = raw.get("parameters", {})
    for pname, ptable in params.items():
        if not isinstance(ptable, dict):
            raise GreenhouseError(f"{source}: 'parameters.{pname}' must be a table")
        for key, value in ptable.items():
            where = f"parameters.{pname}.{key}"
            if key not in _PARAM_KEYS:
                raise GreenhouseError(f"{source}: unknown key '{where}' (allowed: value, bounds, variation)")
            if key == "bounds":
                ok = (
                    isinstance(value, list)
                    and len(value) == 2
                    and all(isinstance(v, int | float) for v in value)
                    and value[0] < value[1]
                )
                if not ok:
                    raise GreenhouseError(f"{source}: '{where}' must be [lower, upper] with lower < upper")
            else:
                _check_number(source, where, value, float, 0.0, math.inf)
    online = _parse_online(raw.get("online", {}), source)
    air = sections["air"]
    site = None
    if sections["site"]:
        for key in ("latitude", "longitude"):
            if key not in sections["site"]:
                raise GreenhouseError(f"{source}: missing 'site.{key}' ([site] needs latitude and longitude)")
        site = Site(**sections["site"])
    return Greenhouse(
        name=str(raw.get("name", Path(source).stem)),
        floor_area=geometry["floor_area"],
        volume=geometry["volume"],
        air_density=air.get("density", 1.205),
        pressure=air.get("pressure", 101.0),
        cover_transmission=sections["cover"].get("transmission", 0.7),
        vents=Vents(**sections["vents"]),
        crop=Crop(**sections["crop"]),
        site=site,
        sensors=tuple(sensors),
        parameters={k: dict(v) for k, v in params.items()},
        source=source,
        online=online,
    )


def _parse_online(table: Any, source: str) -> dict[str, dict[str, Any]]:
    """``[online.<output>]`` tables of online estimator settings, checked key by key."""
    if not isinstance(table, dict):
        raise GreenhouseError(f"{source}: 'online' must be a table of [online.<output>] tables")
    out: dict[str, dict[str, Any]] = {}
    for output, settings in table.items():
        if output not in ONLINE_OUTPUTS:
            raise GreenhouseError(
                f"{source}: unknown key 'online.{output}' (allowed: {', '.join(ONLINE_OUTPUTS)})"
            )
        if not isinstance(settings, dict):
            raise GreenhouseError(f"{source}: 'online.{output}' must be a table")
        out[output] = {}
        for key, value in settings.items():
            if key not in _ONLINE_KEYS:
                raise GreenhouseError(
                    f"{source}: unknown key 'online.{output}.{key}' "
                    f"(allowed: {', '.join(_ONLINE_KEYS)})"
                )
            out[output][key] = check_online_value(source, output, key, value)
    return out


def _check_geometry(geometry: dict[str, Any], source: str) -> None:
    """Both sizes given, and a mean height (volume / floor area) a greenhouse can have."""
    for key in ("floor_area", "volume"):
        if key not in geometry:
            raise GreenhouseError(f"{source}: missing 'geometry.{key}'")
    height = geometry["volume"] / geometry["floor_area"]
    if not MEAN_HEIGHT[0] <= height <= MEAN_HEIGHT[1]:  # a unit slip: cm2, litres, ...
        raise GreenhouseError(
            f"{source}: 'geometry.volume' / 'geometry.floor_area' = {height:.3g} m mean height is "
            f"impossible (expected {MEAN_HEIGHT[0]:g}..{MEAN_HEIGHT[1]:g} m: floor_area in m2, "
            f"volume in m3)")


def check_online_value(source: str, output: str, key: str, value: Any) -> Any:
    """One ``[online.<output>]`` setting checked against its bounds, as the greenhouse file's
    are (``replay --set`` too: a window of 1e9 would otherwise be a memory error)."""
    kind, lo, hi = _ONLINE_KEYS[key]
    return _check_number(source, f"online.{output}.{key}", value, kind, lo, hi)


def _check_number(source: str, where: str, value: Any, kind: type, lo: float, hi: float) -> Any:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise GreenhouseError(f"{source}: '{where}' must be a number, got {value!r}")
    if kind is int and not float(value).is_integer():
        raise GreenhouseError(f"{source}: '{where}' must be a whole number, got {value!r}")
    if not (lo <= value <= hi) or (where.startswith("geometry") and value <= 0):
        raise GreenhouseError(f"{source}: '{where}' = {value!r} is impossible (expected {lo:g}..{hi:g})")
    return kind(value)

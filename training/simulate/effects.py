"""Injectable effects: changes from a given time that are never declared in the CSV.

Each effect is a small frozen dataclass with a ``name``, a ``start`` instant (UTC) and its
parameters. Physical effects change the drivers of the heat and water balances
(:class:`PhysicsDrivers`); sensor effects change what the inside temperature sensor reports.
An effect acts on every sub-step whose midpoint is at or after ``start`` (so the first state
that differs is the first output sample after ``start``) and on every sensor reading at or
after ``start``.

Spec strings (CLI): ``name[@YYYY-MM-DD[THH:MM[:SS]][Z]][:key=value[,key=value...]]``, e.g.
``cover_transmission@2009-11-08T10:00:factor=0.7`` or ``heater@2009-11-05:power=20,setpoint=10``.
Without ``@time`` the effect starts with the simulation. ``none`` means no effect.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, fields
from typing import ClassVar

import numpy as np


@dataclass
class PhysicsDrivers:
    """Per-sub-step arrays that physical effects modify (length = number of sub-steps).

    ``tau_factor`` [-] multiplies the cover solar transmission; ``extra_leak`` [m3 s-1] adds to the
    air exchange; ``cap_factor`` [-] multiplies the heat capacity of the air + fast-mass node;
    ``heaters`` lists (active mask, power [W m-2], setpoint [°C] or NaN, night_only).
    """

    tau_factor: np.ndarray
    extra_leak: np.ndarray
    cap_factor: np.ndarray
    heaters: list[tuple[np.ndarray, float, float, bool]] = field(default_factory=list)

    @classmethod
    def neutral(cls, n: int) -> PhysicsDrivers:
        """Drivers with no effect acting."""
        return cls(np.ones(n), np.zeros(n), np.ones(n))


@dataclass(frozen=True)
class Effect:
    """Base class: an effect named ``name`` acting from ``start`` (datetime64[s], UTC)."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = "physics"  # or "sensor"
    summary: ClassVar[str] = ""
    units: ClassVar[dict[str, str]] = {}
    start: np.datetime64

    def params(self) -> dict:
        """Parameters by name (without ``start``)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "start"}

    def to_dict(self) -> dict:
        """``{"effect", "start", "params"}`` as written to the truth JSON."""
        return {"effect": self.name, "start": str(np.datetime64(self.start, "s")) + "Z",
                "kind": self.kind, "params": self.params(), "units": dict(self.units)}

    def apply_physics(self, drivers: PhysicsDrivers, active: np.ndarray, volume: float) -> None:
        """Change the sub-step drivers where ``active``; ``volume`` [m3] of the house."""

    def sensor_body_offset(self, i_in: np.ndarray, days: np.ndarray) -> np.ndarray | float:
        """Heating [K] of the inside sensor body (also lowers its RH reading)."""
        return 0.0

    def sensor_reading_offset(self, i_in: np.ndarray, days: np.ndarray) -> np.ndarray | float:
        """Error [K] added to the inside temperature reading only."""
        return 0.0


@dataclass(frozen=True)
class CoverTransmission(Effect):
    """Whitening, shading screen, second cover or dust: cover solar transmission × ``factor``."""

    name: ClassVar[str] = "cover_transmission"
    summary: ClassVar[str] = "cover solar transmission x factor (whitening, shading, 2nd cover)"
    units: ClassVar[dict[str, str]] = {"factor": "-"}
    factor: float = 0.7

    def __post_init__(self) -> None:
        if not 0.0 <= self.factor <= 1.5:
            raise ValueError(f"cover_transmission factor must be in [0, 1.5], got {self.factor}")

    def apply_physics(self, drivers: PhysicsDrivers, active: np.ndarray, volume: float) -> None:
        drivers.tau_factor[active] *= self.factor


@dataclass(frozen=True)
class ExtraLeakage(Effect):
    """A door left open: extra air exchange, either ``flow`` [m3 s-1] or ``ach`` [h-1]."""

    name: ClassVar[str] = "extra_leakage"
    summary: ClassVar[str] = "door left open: added air exchange, flow [m3 s-1] or ach [h-1]"
    units: ClassVar[dict[str, str]] = {"flow": "m3 s-1", "ach": "h-1"}
    flow: float | None = None
    ach: float | None = None

    def __post_init__(self) -> None:
        if (self.flow is None) == (self.ach is None):
            raise ValueError("extra_leakage needs exactly one of flow [m3 s-1] or ach [h-1]")
        if (self.flow or 0.0) < 0.0 or (self.ach or 0.0) < 0.0:
            raise ValueError("extra_leakage flow/ach must be >= 0")

    def flow_m3s(self, volume: float) -> float:
        """Added flow [m3 s-1] for a house of ``volume`` [m3]."""
        return self.flow if self.flow is not None else self.ach * volume / 3600.0

    def apply_physics(self, drivers: PhysicsDrivers, active: np.ndarray, volume: float) -> None:
        drivers.extra_leak[active] += self.flow_m3s(volume)


@dataclass(frozen=True)
class Heater(Effect):
    """An undeclared heater of ``power`` [W m-2 of floor] into the air.

    With a ``setpoint`` [°C] it modulates over a 1 K proportional band below the setpoint; with
    ``night_only`` it runs only while the outside global radiation is below 10 W m-2.
    """

    name: ClassVar[str] = "heater"
    summary: ClassVar[str] = "undeclared heat input power [W m-2 floor], optional setpoint, night"
    units: ClassVar[dict[str, str]] = {"power": "W m-2", "setpoint": "degC", "night_only": "0/1"}
    power: float = 20.0
    setpoint: float | None = None
    night_only: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "night_only", bool(self.night_only))  # 1/0 from a spec string
        if self.power < 0.0:
            raise ValueError(f"heater power must be >= 0, got {self.power}")

    def apply_physics(self, drivers: PhysicsDrivers, active: np.ndarray, volume: float) -> None:
        setpoint = np.nan if self.setpoint is None else float(self.setpoint)
        drivers.heaters.append((active, float(self.power), setpoint, bool(self.night_only)))


@dataclass(frozen=True)
class ThermalMass(Effect):
    """Heat capacity of the air + fast-mass node × ``factor`` (water barrels, more crop)."""

    name: ClassVar[str] = "thermal_mass"
    summary: ClassVar[str] = "heat capacity of the air + fast mass node x factor (water barrels)"
    units: ClassVar[dict[str, str]] = {"factor": "-"}
    factor: float = 2.0

    def __post_init__(self) -> None:
        if self.factor <= 0.0:
            raise ValueError(f"thermal_mass factor must be > 0, got {self.factor}")

    def apply_physics(self, drivers: PhysicsDrivers, active: np.ndarray, volume: float) -> None:
        drivers.cap_factor[active] *= self.factor


@dataclass(frozen=True)
class SensorRadiationBias(Effect):
    """Inside temperature sensor heated by the sun: its body is ``k`` × I_in warmer [K W-1 m2].

    The RH channel of the same sensor then reads lower (RH at the body temperature).
    """

    name: ClassVar[str] = "sensor_radiation_bias"
    kind: ClassVar[str] = "sensor"
    summary: ClassVar[str] = "inside sensor heated by sun: +k * I_in, k [K per W m-2]"
    units: ClassVar[dict[str, str]] = {"k": "K W-1 m2"}
    k: float = 0.005

    def sensor_body_offset(self, i_in: np.ndarray, days: np.ndarray) -> np.ndarray:
        return self.k * np.maximum(i_in, 0.0)


@dataclass(frozen=True)
class SensorDrift(Effect):
    """Inside temperature reading drifting linearly at ``rate`` [K d-1] from ``start``."""

    name: ClassVar[str] = "sensor_drift"
    kind: ClassVar[str] = "sensor"
    summary: ClassVar[str] = "inside temperature reading drifts linearly, rate [K per day]"
    units: ClassVar[dict[str, str]] = {"rate": "K d-1"}
    rate: float = 0.2

    def sensor_reading_offset(self, i_in: np.ndarray, days: np.ndarray) -> np.ndarray:
        return self.rate * days


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (CoverTransmission, ExtraLeakage, Heater, ThermalMass, SensorRadiationBias,
                SensorDrift)
}

_SPEC = re.compile(
    r"^(?P<name>[a-z_]+)"
    r"(?:@(?P<time>\d{4}-\d{2}-\d{2}(?:T\d{2}(?::\d{2}(?::\d{2})?)?)?Z?))?"
    r"(?::(?P<params>.*))?$"
)


def describe_effects() -> str:
    """One line per known effect with its parameters and units (for help and errors)."""
    lines = []
    for name, cls in EFFECTS.items():
        params = ", ".join(f"{p} [{u}]" for p, u in cls.units.items())
        lines.append(f"  {name}: {cls.summary}; params: {params}")
    lines.append("  none: no effect")
    return "\n".join(lines)


class EffectSpecError(ValueError):
    """A bad effect spec; its one line names the known effects (``--help`` describes them)."""


def parse_time(text: str) -> np.datetime64:
    """'YYYY-MM-DD[THH:MM[:SS]][Z]' (UTC) → datetime64[s]."""
    return np.datetime64(text.rstrip("Z"), "s")


def _value(text: str) -> float | bool:
    low = text.strip().lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    return float(text)


def parse_effect(spec: str, default_start: np.datetime64) -> Effect | None:
    """An :class:`Effect` from a spec string (``None`` for ``none``); see the module doc."""
    match = _SPEC.match(spec.strip())
    # one line, as every command-line refusal (the parameters: describe_effects, in --help)
    hint = f" (known effects: {', '.join(EFFECTS)}, none; their parameters: --help)"
    if not match:
        raise EffectSpecError(
            f"bad effect spec {spec!r}; write name[@YYYY-MM-DDTHH:MM][:key=value,...]{hint}")
    name = match["name"]
    if name == "none":
        return None
    if name not in EFFECTS:
        raise EffectSpecError(f"unknown effect {name!r}{hint}")
    cls = EFFECTS[name]
    try:
        start = parse_time(match["time"]) if match["time"] else np.datetime64(default_start, "s")
    except ValueError:  # numpy's "Month out of range in datetime string" named neither
        raise EffectSpecError(f"effect {name}: bad start time {match['time']!r}; write "
                              f"YYYY-MM-DD[THH:MM[:SS]] (UTC){hint}") from None
    kwargs: dict = {}
    for item in filter(None, (match["params"] or "").split(",")):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in cls.units:
            raise EffectSpecError(
                f"effect {name}: bad parameter {item!r}; expected one of "
                f"{', '.join(cls.units)}{hint}")
        try:
            kwargs[key] = _value(value)
        except ValueError:
            raise EffectSpecError(f"effect {name}: {key}={value!r} is not a number{hint}") from None
    try:
        return cls(start=start, **kwargs)
    except (TypeError, ValueError) as exc:
        raise EffectSpecError(f"effect {name}: {exc}{hint}") from None


def effect_from_dict(data: dict) -> Effect:
    """Inverse of :meth:`Effect.to_dict` (reads a truth JSON's effect list)."""
    cls = EFFECTS[data["effect"]]
    return cls(start=parse_time(data["start"]), **data.get("params", {}))

"""A grower-like natural-ventilation controller: roof flaps first, side vents after.

Each vent opening follows a proportional demand on the inside air temperature,
``demand = 100 clip((T - T_set) / band, 0, 1)`` [%], through a backlash (hysteresis) of
``hysteresis`` [K]: the vent opens as soon as the demand at T exceeds its position, but only
closes when the demand at ``T + hysteresis`` falls below it. So a vent opened at 25 °C does not
close until the air is back to ``25 - hysteresis``, which stops the motors hunting. Motors move
at a finite speed. Safety rules as in commercial climate computers: rain closes the roof (the
side vents stay), strong wind limits both.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


def proportional(t_air: float, setpoint: float, band: float) -> float:
    """Proportional demand [%] for air temperature ``t_air`` [°C], ``setpoint`` [°C], ``band`` [K]."""
    return 100.0 * min(max((t_air - setpoint) / band, 0.0), 1.0)


def backlash(position: float, t_air: float, setpoint: float, band: float,
             hysteresis: float) -> float:
    """Target opening [%] after hysteresis: open on the rising demand, close ``hysteresis`` K lower."""
    rising = proportional(t_air, setpoint, band)
    falling = proportional(t_air + hysteresis, setpoint, band)
    return min(max(position, rising), falling)


@dataclass(frozen=True)
class VentController:
    """Roof-then-side vent controller.

    ``roof_setpoint``/``side_setpoint`` start of opening [°C]; ``band`` proportional band [K];
    ``hysteresis`` [K]; ``speed`` motor speed [% s-1]; ``wind_limit`` wind speed [m s-1] above
    which openings are capped at ``wind_cap`` [%] until it is ``wind_hysteresis`` [m s-1] lower;
    ``rain_closes_roof`` [bool].
    """

    roof_setpoint: float = 24.0
    side_setpoint: float = 26.5
    band: float = 4.0
    hysteresis: float = 1.0
    speed: float = 100.0 / 180.0
    wind_limit: float = 10.0
    wind_cap: float = 20.0
    wind_hysteresis: float = 2.0
    rain_closes_roof: bool = True

    def storm(self, wind: np.ndarray) -> np.ndarray:
        """Wind alarm [bool] per sample from the (filtered) wind speed [m s-1].

        A Schmitt trigger: on above ``wind_limit``, off only below ``wind_limit -
        wind_hysteresis``, so gusts around the limit do not make the motors hunt.
        """
        out = np.zeros(len(wind), dtype=bool)
        on = False
        for i, u in enumerate(np.asarray(wind, dtype=float).tolist()):
            on = u > self.wind_limit or (on and u > self.wind_limit - self.wind_hysteresis)
            out[i] = on
        return out

    def step(self, t_air: float, storm: bool, rain: float, roof: float, side: float,
             dt: float, now: float = 0.0) -> tuple[float, float]:
        """New (roof, side) positions [%] after ``dt`` [s] from ``roof``, ``side`` [%].

        ``t_air`` [°C] is the controller's air temperature, ``storm`` the wind alarm
        (:meth:`storm`), ``rain`` [0/1]; ``now`` [s since the epoch, UTC] is not used (a
        climate computer does not look at the clock).
        """
        roof_target = backlash(roof, t_air, self.roof_setpoint, self.band, self.hysteresis)
        side_target = backlash(side, t_air, self.side_setpoint, self.band, self.hysteresis)
        if storm:
            roof_target = min(roof_target, self.wind_cap)
            side_target = min(side_target, self.wind_cap)
        if rain > 0.5 and self.rain_closes_roof:
            roof_target = 0.0
        move = self.speed * dt
        roof += min(max(roof_target - roof, -move), move)
        side += min(max(side_target - side, -move), move)
        return roof, side


@dataclass(frozen=True)
class GrowerVents:
    """Vents moved by hand, as on most small farms: no climate computer, no vent signal.

    The grower comes by a few times a day (``visits``, local solar hours, each drawn
    ``± jitter`` [h] and skipped with probability ``skip``), looks at the inside air and sets
    each vent to one of a few notches: roof and sides wide open above ``hot`` [°C], the roof
    half open and the sides a crack above ``warm``, everything closed below ``cool``, else
    left as found. Rain or a storm at a visit closes the roof, wind caps both at ``wind_cap``.
    The last visit of the day closes everything, unless the grower forgets (probability
    ``forget``): then the vents stay open overnight. Between visits nothing moves, whatever
    the weather does; the crank is turned within the visit's step. Stateless and seeded per day
    (``seed``), so a run is reproducible; ``utc_offset`` [h] turns UTC into local solar time.
    """

    visits: tuple[float, ...] = (8.5, 11.0, 13.5, 16.0, 18.5)
    jitter: float = 0.75
    skip: float = 0.25
    forget: float = 0.2
    cool: float = 17.0
    warm: float = 22.0
    hot: float = 26.0
    wind_cap: float = 20.0
    wind_limit: float = 10.0
    utc_offset: float = 0.0
    seed: int = 0

    def storm(self, wind: np.ndarray) -> np.ndarray:
        """Strong wind [bool] per sample (the grower notices it only at a visit)."""
        return np.asarray(wind, dtype=float) > self.wind_limit

    def targets(self, t_air: float, storm: bool, rain: float, roof: float, side: float,
                closing: bool) -> tuple[float, float]:
        """Positions [%] the grower chooses at a visit (``closing``: the evening round)."""
        if closing:
            return 0.0, 0.0
        if t_air > self.hot:
            roof, side = 100.0, 50.0 if t_air < self.hot + 3.0 else 100.0
        elif t_air > self.warm:
            roof, side = 50.0, 25.0 if t_air > 0.5 * (self.warm + self.hot) else 0.0
        elif t_air < self.cool:
            roof, side = 0.0, 0.0
        if rain > 0.5 or storm:
            roof = 0.0 if rain > 0.5 else min(roof, self.wind_cap)
            side = min(side, self.wind_cap) if storm else side
        return roof, side

    def step(self, t_air: float, storm: bool, rain: float, roof: float, side: float,
             dt: float, now: float = 0.0) -> tuple[float, float]:
        """Positions [%] after ``dt`` [s] ending at ``now`` [s since the epoch, UTC]."""
        hours = now / 3600.0 + self.utc_offset
        day = int(hours // 24.0)
        plan = _visit_plan(self.seed, day, self.visits, self.jitter, self.skip, self.forget)
        local = hours - 24.0 * day
        for when, closing in plan:
            if local - dt / 3600.0 < when <= local:
                roof, side = self.targets(t_air, storm, rain, roof, side, closing)
        return roof, side


@lru_cache(maxsize=64)
def _visit_plan(seed: int, day: int, visits: tuple[float, ...], jitter: float, skip: float,
                forget: float) -> tuple[tuple[float, bool], ...]:
    """The day's visits as (local hour, is the closing round), drawn from (seed, day)."""
    rng = np.random.default_rng([seed, day + 100_000])
    times = np.asarray(visits) + rng.uniform(-jitter, jitter, len(visits))
    keep = rng.random(len(visits)) >= skip
    forgot = rng.random() < forget
    plan = [(float(t), False) for t in times[:-1][keep[:-1]]]
    if not forgot:
        plan.append((float(times[-1]), True))
    return tuple(plan)

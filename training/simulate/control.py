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
             dt: float) -> tuple[float, float]:
        """New (roof, side) positions [%] after ``dt`` [s] from ``roof``, ``side`` [%].

        ``t_air`` [°C] is the controller's air temperature, ``storm`` the wind alarm
        (:meth:`storm`), ``rain`` [0/1].
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

"""Heat-transfer coefficients between the simulator's nodes (scalar, used inside the loop).

References
----------
- Papadakis, Frangoudakis & Kyritsis (1992), J. Agric. Eng. Res. 51: natural convection at the
  inner cover surface, ``h = 1.86 |dT|^(1/3)`` [W m-2 K-1].
- Watmuff, Charters & Proctor (1977), COMPLES 2: forced convection at an outer surface,
  ``h = 2.8 + 3.0 u`` [W m-2 K-1] with ``u`` the wind speed [m s-1].
- Bot (1983), PhD thesis Wageningen, ch. 5: floor-air convection, stronger when the floor is
  warmer than the air (unstable) than when it is colder.
- Incropera & DeWitt, *Fundamentals of Heat and Mass Transfer*: grey-body radiation between two
  surfaces written as a conductance ``eps sigma (T1² + T2²)(T1 + T2)`` [W m-2 K-1] (exact
  factorisation of ``eps sigma (T1⁴ - T2⁴)``, temperatures in kelvin).
"""

from __future__ import annotations

from gateway.model.psychrometrics import KELVIN

SIGMA = 5.670374419e-8
"""Stefan-Boltzmann constant [W m-2 K-4]."""


def natural_convection(dt: float, a: float, b: float) -> float:
    """``h = a |dt|^(1/3) + b`` [W m-2 K-1] for a temperature difference ``dt`` [K]."""
    return a * abs(dt) ** (1.0 / 3.0) + b


def wind_convection(wind: float, a: float, b: float) -> float:
    """``h = a + b u`` [W m-2 K-1] for wind speed ``wind`` [m s-1]."""
    return a + b * wind


def floor_convection(t_floor: float, t_air: float, a_up: float, a_down: float) -> float:
    """Floor-air convection coefficient [W m-2 K-1] (unstable if the floor is warmer) [°C in]."""
    dt = t_floor - t_air
    return (a_up if dt > 0.0 else a_down) * abs(dt) ** (1.0 / 3.0) + 0.3


def radiative_conductance(t1: float, t2: float, eps: float) -> float:
    """Radiative conductance [W m-2 K-1] between surfaces at ``t1``, ``t2`` [°C], emissivity ``eps``.

    ``G (t1 - t2)`` equals ``eps sigma (T1⁴ - T2⁴)`` exactly.
    """
    k1 = t1 + KELVIN
    k2 = t2 + KELVIN
    return eps * SIGMA * (k1 * k1 + k2 * k2) * (k1 + k2)

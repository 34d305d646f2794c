"""Natural ventilation through roof and side vents, and leakage.

References
----------
- Kittas, Boulard & Papadakis (1997), Trans. ASAE 40(2): 415-425, combined stack and wind driven
  flow through roof and side openings:
  ``G = Cd sqrt( (A_r A_s / sqrt(A_r² + A_s²))² 2 g h dT / T_out + ((A_r + A_s)/2)² Cw u² )``.
- Boulard & Baille (1995), J. Agric. Eng. Res. 61: stack flow through a single roof opening
  ``G = Cd (A_r / 3) sqrt(g dT H_r / T_out)`` with ``H_r`` the opening height; added in quadrature
  so a roof-only opening still breathes on buoyancy.
- Thesis III.33-III.34 (docs/model-notes.md §3): opening area of side vents (linear in the signal) and
  roof flaps (``2 L W sin(angle / 2)``).
- Muñoz et al. (1999), J. Agric. Eng. Res. 73: insect screens cut the flow roughly by half
  (here a factor on Cd).
"""

from __future__ import annotations

import math

from gateway.model.psychrometrics import GRAVITY, KELVIN


def roof_area(opening: float, n: int, length: float, width: float, max_angle: float) -> float:
    """Open area [m2] of ``n`` roof flaps ``length`` × ``width`` [m] at ``opening`` [%].

    The flap angle is ``opening / 100 * max_angle`` [deg]; the area is that of the two triangles
    and the long slot, ``2 L W sin(angle / 2)`` per flap (thesis III.34).
    """
    angle = math.radians(opening / 100.0 * max_angle)
    return n * 2.0 * length * width * math.sin(angle / 2.0)


def side_area(opening: float, n: int, length: float, height: float) -> float:
    """Open area [m2] of ``n`` rolling side vents ``length`` × ``height`` [m] at ``opening`` [%]."""
    return n * length * height * opening / 100.0


def kittas_flow(a_roof: float, a_side: float, dt: float, t_out: float, wind: float,
                vent_height: float, cd: float, cw: float, roof_opening_height: float) -> float:
    """Ventilation flow G [m3 s-1] (Kittas et al. 1997 with a single-opening stack term).

    ``a_roof``, ``a_side`` open areas [m2]; ``dt`` = T_in - T_out [K]; ``t_out`` [°C];
    ``wind`` [m s-1]; ``vent_height`` distance between vent centres [m]; ``cd`` discharge and
    ``cw`` wind coefficients [-]; ``roof_opening_height`` [m] for the single-opening term.
    """
    t_k = t_out + KELVIN
    buoy = GRAVITY * abs(dt) / t_k
    both = 0.0
    if a_roof > 0.0 and a_side > 0.0:
        both = (a_roof * a_side) ** 2 / (a_roof * a_roof + a_side * a_side) * 2.0 * vent_height
    single = (a_roof / 3.0) ** 2 * roof_opening_height
    wind_term = (0.5 * (a_roof + a_side)) ** 2 * cw * wind * wind
    return cd * math.sqrt((both + single) * buoy + wind_term)


def leakage_flow(volume: float, ach: float, ach_wind: float, wind: float) -> float:
    """Leakage flow [m3 s-1] of a house of ``volume`` [m3]: ``(ach + ach_wind u) V / 3600``."""
    return (ach + ach_wind * wind) * volume / 3600.0

"""Model inputs ("drivers") prepared once from a resampled series and a greenhouse.

Derived quantities that do not depend on the simulated state are computed here, once per
series, so the hot loops only index arrays.
"""

from __future__ import annotations

import numpy as np

from gateway.greenhouse import Greenhouse, Vents
from gateway.model import psychrometrics as psy
from gateway.model import sky, solar
from gateway.series import Series


def roof_vent_area(vents: Vents, opening: np.ndarray) -> np.ndarray:
    """Roof (flap) opening area A_r [m2] from the opening signal [%] (III.34).

    ``A_r = n L 2 W sin(U/100 * angle_max / 2)``, the flap's open area as a function of its
    opening angle (docs/model-notes.md §3).
    """
    angle = np.radians(np.asarray(opening, dtype=float) / 100.0 * vents.roof_max_angle / 2.0)
    return vents.roof_count * 2.0 * vents.roof_length * vents.roof_width * np.sin(angle)


def side_vent_area(vents: Vents, opening: np.ndarray) -> np.ndarray:
    """Side vent opening area A_s [m2] from the opening signal [%] (III.33, linear)."""
    return vents.side_count * vents.side_length * vents.side_height * np.asarray(opening) / 100.0


def site_of(gh: Greenhouse) -> tuple[float, float] | None:
    """(latitude, longitude) of the greenhouse, None when its description gives no site."""
    return None if gh.site is None else (gh.site.latitude, gh.site.longitude)


def clock_of(gh: Greenhouse) -> solar.SolarClock:
    """The clock of the time-of-day features at the greenhouse: local mean solar time at its
    site's longitude, UTC when its description gives no site (solar.py ``solar_clock``)."""
    return solar.solar_clock(None if gh.site is None else gh.site.longitude)


def prepare_drivers(series: Series, gh: Greenhouse, cloud: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Arrays (length T) that the flux terms read.

    Measured columns pass through (NaN for gaps); optional columns get physically neutral
    values when absent (closed vents, the crop's LAI of the greenhouse description, no soil
    flux is not possible: terms that need ``t_soil`` must find it). Derived: ``cloud`` [-] and
    ``t_sky`` [°C] from the outside humidity and the cloudiness read from the radiation at the
    greenhouse's site (sky.py; in place of III.13), ``h_o`` [W m-2 K-1] (III.9), ``p_w_in``
    inside vapour pressure [kPa] (III.4), ``a_roof``/``a_side`` [m2] (III.33–III.34).
    ``cloud``: the cloud fraction when the caller tracks it itself (the online estimator, one
    row at a time: sky.CloudTracker), else computed from the whole series.
    """
    n = len(series)
    x: dict[str, np.ndarray] = {}
    for name, values in series.columns.items():
        x[name] = np.asarray(values, dtype=float)
    nan = np.full(n, np.nan)
    for name in ("t_in", "t_out", "rh_in", "i_glob", "wind"):
        x.setdefault(name, nan)
    x["i_glob"] = solar.measured_global(x["i_glob"])
    if cloud is None:
        cloud = sky.cloud_fraction(series.time, x["i_glob"], site_of(gh), series.step)
    x["cloud"] = np.asarray(cloud, dtype=float)
    x["t_sky"] = sky.sky_temperature(x["t_out"], x.get("rh_out"), x["cloud"])
    x["h_o"] = 2.8 + 1.2 * x["wind"]
    x["p_w_in"] = psy.vapour_pressure(x["t_in"], x["rh_in"])
    if "lai" not in series:
        x["lai"] = np.full(n, gh.crop.lai)
    roof = x.get("vent_roof", np.zeros(n))
    side = x.get("vent_side", np.zeros(n))
    x["a_roof"] = roof_vent_area(gh.vents, np.nan_to_num(roof))
    x["a_side"] = side_vent_area(gh.vents, np.nan_to_num(side))
    return hold_means(x) if series.sampling == "mean" else x


NOT_HELD = ("t_in", "i_in", "time")
"""Columns ``hold_means`` leaves alone: the state and the measured outputs are compared as
they were measured; only the drivers are read through the hold."""
NON_NEGATIVE = ("a_roof", "a_side", "wind", "h_o")


def hold_means(x: dict[str, np.ndarray], keep: tuple[str, ...] = NOT_HELD) -> dict[str, np.ndarray]:
    """Drivers given as means over each step → the values the first-order hold of the step
    (gateway/model/step.py) must read, ``u_k - (u_k-1 - 2 u_k + u_k+1) / 12``.

    Over one step from a measured mean state, the balance sees the drivers weighted by a
    triangle over the two means it spans (the box of the averaging convolved with the step),
    not the straight line between the two means that the hold draws: for a smooth driver the
    two differ by the second difference / 12, and this correction makes them agree to third
    order (exact for cubic drivers at small λΔ). Without it, rough drivers (radiation under
    passing clouds) bias the identified parameters (docs/model.md). Where a neighbour is
    missing (the ends, a gap) the value is left as it is.
    """
    out = dict(x)
    for name, v in x.items():
        if name in keep or name.startswith("_"):
            continue
        v = np.asarray(v, dtype=float)
        if v.ndim != 1 or len(v) < 3:
            continue
        d2 = np.zeros_like(v)
        d2[1:-1] = v[:-2] - 2.0 * v[1:-1] + v[2:]
        held = np.where(np.isfinite(d2), v - d2 / 12.0, v)
        out[name] = np.maximum(held, 0.0) if name in NON_NEGATIVE else held
    return out

"""A night-sky level fitted on the calibration part (issue 10: the sky the kit cannot see).

The kit reads the cloudiness from the daytime radiation and carries it through the night,
relaxing with ``RELAX_S`` towards a trailing daytime prior (gateway/model/sky.py). At night
that carried value hardly tells the sky: over 9427 measured Bleiswijk night rows its
correlation with the measured sky depression is r = −0.08 (docs/effects.md, "The night sky").
When two clear calibration nights are carried as overcast, the base's sky-loss coefficient
(c_lw_sky, or the prototype's c_thermal, III.21) grows to explain their cooling, and held-out
nights with the opposite error are missed by 1–2.5 K.

This part replaces the prior the carried cloud relaxes to by a site-level night cloud
fraction c_n fitted on the calibration part with the rest of the base (a base parameter, not
an effect: it is the weather, not the greenhouse):

    c = c_kit + r (c_n − c_p)              r = 1 − e^(−Δt/RELAX_S), c_p the trailing prior
    ε = (1 − 0.84 c) ε_clear + 0.84 c      (Unsworth & Monteith 1975; sky.py)
    T_sky = ε^(1/4) T_out                  (every term that reads T_sky sees this one)

Right after a daytime reading (r = 0) the kit's value stands; through the night the fitted
level takes over, so the sky loss is fitted against one sky for all calibration nights, not
against each night's misread. By day, where the cloud is read, nothing changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model import psychrometrics as psy
from gateway.model import sky
from gateway.model.drivers import site_of
from gateway.model.terms import ALWAYS, Index, Parameter
from gateway.series import Series

RELAX = "sky_relax"
"""Driver: the share r [-] of the prior in the carried cloud fraction."""
PRIOR = "cloud_prior"
"""Driver: the prior c_p [-] the carried cloud fraction relaxes to."""
EPS_CLEAR = "eps_clear"
"""Driver: the clear-sky emissivity [-] (Brutsaert 1975; Swinbank without humidity)."""
LEVEL = Parameter("c_sky_night", "-", 0.0, 1.0, sky.DEFAULT_CLOUD, None, ALWAYS,
                  "night cloud fraction of the site, in place of the kit's trailing prior")


def sky_drivers(series: Series, gh: Greenhouse, x: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The drivers the part reads (``RELAX``, ``PRIOR``, ``EPS_CLEAR``), from the same series
    and site as the kit's cloud fraction (gateway/model/drivers.py)."""
    i_glob = series.columns.get("i_glob", np.full(len(series), np.nan))  # read as sky.py reads it
    _, r, prior = sky.carried_cloud(series.time, i_glob, site_of(gh), series.step)
    rh = x.get("rh_out")
    e = None if rh is None else psy.vapour_pressure(x["t_out"], rh)
    return {RELAX: r, PRIOR: prior, EPS_CLEAR: sky.clear_sky_emissivity(x["t_out"], e)}


class NightSky:
    """The fitted night cloud level: the sky temperature the terms read, per candidate."""

    name = "night_sky"
    equation = "sky.py, prior replaced by a fitted level"

    def __init__(self, lower: float = LEVEL.lower, upper: float = LEVEL.upper) -> None:
        """``lower``/``upper``: the level's bounds (base.NIGHT_SKY_WIDTH narrows them)."""
        default = min(max(LEVEL.default, lower), upper)
        self.parameters = (replace(LEVEL, lower=lower, upper=upper, default=default),)

    def t_sky(self, p: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray], t: Index) -> np.ndarray:
        """Sky temperature [°C] (module docstring); broadcasts candidates against time."""
        c = x["cloud"][t] + x[RELAX][t] * (p[LEVEL.name] - x[PRIOR][t])
        return sky.radiative_temperature(x["t_out"][t], sky.sky_emissivity(x[EPS_CLEAR][t], c))

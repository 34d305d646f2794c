"""Apparent sky temperature from the kit's outside readings: humidity and cloudiness (issue 10).

A greenhouse loses heat by long-wave radiation to the sky. The thesis takes the sky temperature
from the outside air temperature alone (Swinbank, III.13), i.e. always a clear sky of average
humidity; a real sky is 10–15 K warmer under cloud. The kit measures no long-wave radiation,
but it measures what sets it: the air's vapour pressure (clear-sky emissivity) and the global
radiation, whose ratio to the clear-sky radiation tells how cloudy the sky is by day.

    ε_clear = 1.24 (e_a / T_a)^(1/7)            e_a [hPa], T_a [K]   (Brutsaert 1975, eq. 11)
    ε_clear = 9.2e-6 T_a²                       without humidity     (Swinbank 1963, eq. 10)
    k = Σ I_glob / Σ I_clear                    over the last ``WINDOW_S`` of strong clear sky
    c = ((1 − k) / 0.75)^(1/3.4)                (Kasten & Czeplak 1980: k = 1 − 0.75 c^3.4)
    ε = (1 − 0.84 c) ε_clear + 0.84 c           (Unsworth & Monteith 1975; Campbell & Norman
                                                 1998, eq. 10.12)
    T_sky = ε^(1/4) T_a                         (the sky as a black body of equal emission)

Cloudiness is read by day only, where the clear sky is strong (``STRONG_CLEAR``): at low sun a
clear-sky index is noise, and hourly-mean radiation stamped at the end of the hour (the
Bleiswijk file) lags the computed sun by half an hour. Ratios of sums over a few hours are
robust to both. Through the night the evening's value is held (no later reading is used:
the same value live as in a replay). Before the first daylight, and when the site is unknown
(no ``[site]`` and no ``--site``: the sun's position cannot be computed), the cloud fraction is
``DEFAULT_CLOUD``, and the humidity still sets the clear-sky part.

Checked against the measured apparent sky temperature of the Bleiswijk file (51 days of a
pyrgeometer-derived tSky, tests/test_sky.py): RMSE 6.1 K, bias +1.3 K, against 14.9 K and
−13.8 K for III.13 (docs/effects.md, "Sky temperature").

References
----------
- Brutsaert, W. (1975), On a derivable formula for long-wave radiation from clear skies,
  Water Resour. Res. 11(5), 742–744.
- Swinbank, W. C. (1963), Long-wave radiation from clear skies, Q. J. R. Meteorol. Soc. 89,
  339–348.
- Kasten, F. & Czeplak, G. (1980), Solar and terrestrial radiation dependent on the amount and
  type of cloud, Solar Energy 24, 177–189.
- Unsworth, M. H. & Monteith, J. L. (1975), Long-wave radiation at the ground I, Q. J. R.
  Meteorol. Soc. 101, 13–24; Campbell, G. S. & Norman, J. M. (1998), An Introduction to
  Environmental Biophysics, 2nd ed., Springer, ch. 10.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import ArrayLike

from gateway.model import psychrometrics as psy
from gateway.model import solar

WINDOW_S = 2 * 3600.0
"""Trailing span over which measured and clear-sky radiation are summed [s]."""
STRONG_CLEAR = 100.0
"""Clear-sky global radiation above which a sample tells the cloudiness [W m-2]."""
MIN_STRONG_S = 1800.0
"""Strong-sun time needed inside the window before the index is updated [s]."""
RELAX_S = 4 * 3600.0
"""Time constant [s] with which the last daytime cloudiness relaxes towards the prior at night:
the e-folding lag of the autocorrelation of the measured sky depression T_sky − T_out in the
51 Bleiswijk days (0.78 at 1 h, 0.51 at 3 h, 0.28 at 6 h, 0.06 at 12 h)."""
PRIOR_S = 3 * 86400.0
"""The prior is the mean daytime cloud fraction of this trailing span [s]."""
DEFAULT_CLOUD = 0.6
"""Cloud fraction before the first daylight reading and without a site [-] (the 51 Bleiswijk
autumn days average 0.63 by the formula above; a prior, not a fit)."""
KC_A, KC_B = 0.75, 3.4
"""Kasten & Czeplak (1980): I / I_clear = 1 − KC_A c^KC_B."""
CLOUD_EMISSIVITY = 0.84
"""Unsworth & Monteith (1975): share of the cloudy sky's emission above the clear sky's."""

WITHOUT_HUMIDITY = ("the sky temperature's clear-sky emissivity comes from the outside air "
                    "temperature alone (Swinbank 1963) instead of from its vapour pressure "
                    "(Brutsaert 1975; gateway/model/sky.py), so the long-wave loss to the sky on "
                    "clear nights is less certain: a dry and a humid night of the same "
                    "temperature get the same sky")
"""What a run without the outside humidity loses, as its notes and the live log say it."""


def clear_sky_emissivity(t_air: ArrayLike, vapour_pressure: ArrayLike | None = None) -> np.ndarray:
    """Clear-sky emissivity [-] at air temperature ``t_air`` [°C] and vapour pressure [kPa]
    (Brutsaert 1975); where the vapour pressure is missing, Swinbank's (1963) 9.2e-6 T²."""
    t_k = np.asarray(t_air, dtype=float) + psy.KELVIN
    swinbank = 9.2e-6 * t_k**2
    if vapour_pressure is None:
        return swinbank
    e_hpa = 10.0 * np.asarray(vapour_pressure, dtype=float)
    with np.errstate(invalid="ignore"):
        brutsaert = 1.24 * np.maximum(e_hpa / t_k, 0.0) ** (1.0 / 7.0)
    return np.where(np.isfinite(brutsaert), brutsaert, swinbank)


def cloud_fraction_from_index(k: ArrayLike) -> np.ndarray:
    """Cloud fraction c [0, 1] from the clear-sky index k [-] (Kasten & Czeplak 1980 inverted):
    k ≥ 1 is clear, k ≤ 0.25 overcast."""
    kc = np.clip(np.asarray(k, dtype=float), 1.0 - KC_A, 1.0)
    return ((1.0 - kc) / KC_A) ** (1.0 / KC_B)


def sky_emissivity(eps_clear: ArrayLike, cloud: ArrayLike) -> np.ndarray:
    """All-sky emissivity [-] (Unsworth & Monteith 1975)."""
    c = np.clip(np.asarray(cloud, dtype=float), 0.0, 1.0)
    return (1.0 - CLOUD_EMISSIVITY * c) * np.asarray(eps_clear, dtype=float) + CLOUD_EMISSIVITY * c


def sky_temperature(t_out: ArrayLike, rh_out: ArrayLike | None, cloud: ArrayLike) -> np.ndarray:
    """Apparent sky temperature [°C] from outside air temperature [°C], relative humidity [%]
    (None or NaN: Swinbank's clear sky) and cloud fraction [-]."""
    t_out = np.asarray(t_out, dtype=float)
    e = None if rh_out is None else psy.vapour_pressure(t_out, rh_out)
    return radiative_temperature(t_out, sky_emissivity(clear_sky_emissivity(t_out, e), cloud))


def radiative_temperature(t_out: ArrayLike, eps: ArrayLike) -> np.ndarray:
    """Apparent sky temperature [°C] of a sky of emissivity ``eps`` [-] over air at ``t_out``
    [°C]: σ T_sky⁴ = ε σ T_out⁴."""
    return np.asarray(eps, dtype=float)**0.25 * (np.asarray(t_out, dtype=float) + psy.KELVIN) \
        - psy.KELVIN


def clear_sky(time: np.ndarray, latitude: float, longitude: float) -> np.ndarray:
    """Clear-sky global radiation [W m-2] at UTC ``time`` (solar.py: NOAA sun, Haurwitz)."""
    return solar.clear_sky_global(solar.solar_position(time, latitude, longitude).cos_zenith)


def cloud_fraction(time: np.ndarray, i_glob: ArrayLike, site: tuple[float, float] | None,
                   step: float) -> np.ndarray:
    """Cloud fraction [-] at each sample, causal: from the clear-sky index of the last
    ``WINDOW_S`` of strong-sun samples, held through the night (module docstring).
    ``DEFAULT_CLOUD`` everywhere when ``site`` is None. ``step`` [s] is the sampling period."""
    return carried_cloud(time, i_glob, site, step)[0]


def carried_cloud(time: np.ndarray, i_glob: ArrayLike, site: tuple[float, float] | None,
                  step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cloud fraction c, relaxation weight r, prior c_p) at each sample: between daytime
    readings c = c_p + (c_last − c_p) e^(−Δt/RELAX_S), so r = 1 − e^(−Δt/RELAX_S) is the share
    of the prior in c (0 where the cloud is read, 1 before the first reading and without a
    site, where c_p = c = ``DEFAULT_CLOUD``). A level fitted in place of the prior enters as
    c + r (level − c_p) (gateway/diagnose/night_sky.py). ``i_glob`` is read through
    ``solar.measured_global`` (a negative night offset counts as 0), as ``CloudTracker`` reads it."""
    n = len(time)
    if site is None:
        return np.full(n, DEFAULT_CLOUD), np.ones(n), np.full(n, DEFAULT_CLOUD)
    i = solar.measured_global(i_glob)
    clear = clear_sky(time, *site)
    strong = (clear >= STRONG_CLEAR) & np.isfinite(i)
    t = np.asarray(time, dtype="datetime64[s]").astype(np.int64).astype(float)
    zero = np.zeros(1)
    s_i = np.concatenate([zero, np.cumsum(np.where(strong, i, 0.0))])
    s_c = np.concatenate([zero, np.cumsum(np.where(strong, clear, 0.0))])
    s_n = np.concatenate([zero, np.cumsum(strong)])
    first = np.searchsorted(t, t - WINDOW_S, side="right")  # samples in (t - W, t]
    last = np.arange(1, n + 1)
    count = s_n[last] - s_n[first]
    ok = strong & (count * step >= MIN_STRONG_S)
    k = np.where(ok, (s_i[last] - s_i[first]) / np.where(ok, s_c[last] - s_c[first], 1.0), np.nan)
    c = np.where(ok, cloud_fraction_from_index(k), 0.0)
    # the prior: mean daytime cloud fraction of the last PRIOR_S (causal climatology)
    s_c2 = np.concatenate([zero, np.cumsum(c)])
    s_n2 = np.concatenate([zero, np.cumsum(ok)])
    back = np.searchsorted(t, t - PRIOR_S, side="right")
    n_prior = s_n2[last] - s_n2[back]
    prior = np.where(n_prior > 0, (s_c2[last] - s_c2[back]) / np.maximum(n_prior, 1), DEFAULT_CLOUD)
    # between daytime readings: relax from the last one towards the prior held at it
    idx = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
    j = np.maximum(idx, 0)
    decay = np.exp(-(t - t[j]) / RELAX_S)
    held = prior[j] + (c[j] - prior[j]) * decay
    seen = idx >= 0
    return (np.where(seen, held, DEFAULT_CLOUD), np.where(seen, 1.0 - decay, 1.0),
            np.where(seen, prior[j], DEFAULT_CLOUD))


class CloudTracker:
    """The same cloud fraction as :func:`cloud_fraction`, one sample at a time (online use)."""

    def __init__(self, site: tuple[float, float] | None, step: float) -> None:
        self.site, self.step = site, float(step)
        self._sun: deque[tuple[float, float, float]] = deque()  # (t, i_glob, clear), strong sun
        self._day: deque[tuple[float, float]] = deque()  # (t, c) of daytime readings
        self._day_sum = 0.0
        self._last: tuple[float, float, float] | None = None  # (t, c, prior) of the last reading
        self.cloud = DEFAULT_CLOUD

    def update(self, time: np.datetime64 | None, i_glob: float) -> float:
        """Take the sample at ``time`` (UTC); return the cloud fraction in force at it."""
        if self.site is None or time is None:
            return self.cloud
        # numpy's stubs have no datetime64(datetime64, unit) overload; numpy takes it
        stamp = np.datetime64(time, "s")  # type: ignore[call-overload]
        t = float(stamp.astype(np.int64))
        clear = float(clear_sky(np.array([stamp]), *self.site)[0])
        while self._sun and self._sun[0][0] <= t - WINDOW_S:
            self._sun.popleft()
        while self._day and self._day[0][0] <= t - PRIOR_S:
            self._day_sum -= self._day.popleft()[1]
        if clear >= STRONG_CLEAR and np.isfinite(i_glob):
            self._sun.append((t, float(solar.measured_global(i_glob)), clear))
            if len(self._sun) * self.step >= MIN_STRONG_S:
                k = sum(b[1] for b in self._sun) / sum(b[2] for b in self._sun)
                c = float(cloud_fraction_from_index(k))
                self._day.append((t, c))
                self._day_sum += c
                self._last = (t, c, self._day_sum / len(self._day))
        if self._last is not None:
            t0, c0, prior = self._last
            self.cloud = prior + (c0 - prior) * float(np.exp(-(t - t0) / RELAX_S))
        return self.cloud

    def state(self) -> dict:
        """Everything ``update`` depends on, JSON-ready (the live gateway saves it with the
        estimator, so a restart resumes the same cloudiness)."""
        return {"sun": [list(b) for b in self._sun], "day": [list(b) for b in self._day],
                "day_sum": self._day_sum, "last": list(self._last) if self._last else None,
                "cloud": self.cloud}

    def restore(self, state: dict) -> None:
        """Continue from a :meth:`state` (of a tracker of the same site and step)."""
        # unpacked, so an entry of the wrong length fails here, not at a later update
        self._sun = deque((float(t), float(i), float(c)) for t, i, c in state["sun"])
        self._day = deque((float(t), float(c)) for t, c in state["day"])
        self._day_sum = float(state["day_sum"])
        last = state["last"]
        if last is None:
            self._last = None
        else:
            t, c, prior = last
            self._last = (float(t), float(c), float(prior))
        self.cloud = float(state["cloud"])

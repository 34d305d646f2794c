"""Issue 10: the day test, a flag for unexplained structure that does not need a bad base.

Days are the units. Each day's residual is summarised twice: by half-hour of the clock (a
scheduled action) and by bins of the plant's own state (a controller acting on what it
measures, e.g. vents opening above a temperature, whatever the hour). Days and clock are the
site's local mean solar time (gateway/model/solar.py ``SolarClock``): a day starts at local
midnight wherever the house stands. Per column, Welch t of the held-out days against the
calibration days; the statistic is the largest |t| over both families, and its null comes from
swapping whole days between the parts, so one null covers both families and the family-wise
false-flag rate stays α when days are exchangeable.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from itertools import combinations
from math import comb

import numpy as np

from gateway.model.solar import DAY_S, UTC_CLOCK, SolarClock

BIN_S = 1800.0
"""Width of the clock bins [s]."""
UNEXPLAINED_ALPHA = 0.05
"""Family-wise false-flag rate of ``day_test`` over all clock and state bins."""
PERM_MAX = 4000
"""Day splits of the null: all of them when there are at most this many, else this many drawn
(fixed seed, so the diagnosis stays deterministic)."""
STATE_BINS = 8
"""Bins per state variable, at pooled quantiles of both parts (split-free, so the null stays
exact)."""
MIN_DAYS = 3
"""Days a column needs in each part to count: a Welch t over two days has a tail the day-swap
null (which mixes the days, so rarely leaves a column that thin) does not reproduce, and a
state band reached by one part only (a warmer week) is thin exactly in the observed split."""
STATE_LABEL = {"t_model": ("inside temperature", "°C"), "dt_model": ("inside − outside", "K"),
               "i_glob": ("global radiation", "W m-2")}
"""State variables from kit sensors (``controller_state``) and how the signature names them."""


@dataclass
class StateBin:
    """A state bin whose |t| exceeds the null's 1 − α quantile: variable, range, held-out minus
    calibration mean residual there [K] (each day's level removed)."""
    name: str
    lo: float
    hi: float
    diff: float


@dataclass
class DayTest:
    """``day_test``'s result: family-wise p, the largest |Welch t|, the clock bins (half-hours
    after midnight of the test's clock, local solar time at the site) whose |t| exceeds the
    null's 1 − α quantile with the held-out minus calibration mean sharp residual there [K],
    the state bins likewise; days in each part."""
    p: float
    t_max: float
    bins: list[int]
    diff: list[float]
    n_held: int
    n_calib: int
    state: list[StateBin] = field(default_factory=list)


def controller_state(x: dict[str, np.ndarray], a: int, r: np.ndarray) -> dict[str, np.ndarray]:
    """What a climate controller acts on, over rows [a, a + len(r)): the inside temperature,
    its excess over outside (the vent's drive) and global radiation. Inside temperature is the
    measured one minus the residual (the model's): binning the residual on a variable that
    contains it would tie bin and residual, more so in the part whose residual is larger."""
    b = a + len(r)
    t = x["t_in"][a:b] - r
    return {"t_model": t, "dt_model": t - x["t_out"][a:b], "i_glob": x["i_glob"][a:b]}


def _cells(day: np.ndarray, key: np.ndarray, r: np.ndarray, nb: int,
           min_n: int = 1) -> np.ndarray:
    """Per day (row) and bin ``key`` (0..nb-1, -1 none), the mean of ``r``; NaN where a cell
    holds fewer than ``min_n`` samples."""
    ok = np.isfinite(r) & (key >= 0)
    nd = int(day.max()) + 1 if len(day) else 0
    cell = day * nb + key
    tot = np.bincount(cell[ok], weights=r[ok], minlength=nd * nb).reshape(nd, nb)
    cnt = np.bincount(cell[ok], minlength=nd * nb).reshape(nd, nb)
    return np.where(cnt >= min_n, tot / np.maximum(cnt, 1), np.nan)


def nan_median(a: np.ndarray) -> np.ndarray:
    """Median of the finite values of ``a`` along its last axis; NaN, said explicitly and
    without numpy's "All-NaN slice" warning, where there is none (the hours before a record's
    first reading in its first day, a day without readings of a state variable)."""
    some = np.isfinite(a).any(axis=-1)
    if some.all():
        return np.nanmedian(a, axis=-1)
    med = np.nanmedian(np.where(some[..., None], a, 0.0), axis=-1)
    return np.where(some, med, np.nan)


def sharp_part(m: np.ndarray) -> np.ndarray:
    """Day profiles ``m`` (..., clock bins of ``BIN_S``) minus their own circular running
    median over ±2 h: what is left of the smooth daily course a weather regime moves."""
    nb = m.shape[-1]
    w = int(round(2 * 3600 / BIN_S))
    idx = (np.arange(nb)[:, None] + np.arange(-w, w + 1)[None, :]) % nb
    return m - nan_median(m[..., idx])


def clock_label(j: int) -> str:
    """Clock bin ``j`` (half-hours after midnight of its clock) as HH:MM; the caller names the
    clock (``SolarClock.name``)."""
    return f"{j // 2:02d}:{30 * (j % 2):02d}"


def _clock_units(day: np.ndarray, sec: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per day, the half-hour means minus their own circular running median over ±2 h
    (``sharp_part``); (days, bins). ``sec``: seconds of the clock (``SolarClock.seconds``)."""
    nb = int(DAY_S // BIN_S)
    return sharp_part(_cells(day, (sec % DAY_S) // int(BIN_S), r, nb))


def _state_units(day: np.ndarray, v: np.ndarray, edges: np.ndarray, r: np.ndarray,
                 min_n: int) -> np.ndarray:
    """Per day, the mean residual in each state bin (at least half an hour of samples) minus
    the median of the day's bins (its level: a regime's offset cancels); (days, bins)."""
    nb = len(edges) - 1
    key = np.where(np.isfinite(v), np.clip(np.searchsorted(edges, v, "right") - 1, 0, nb - 1), -1)
    m = _cells(day, key, r, nb, min_n)
    return m - nan_median(m)[:, None]


def _edges(parts: list[np.ndarray]) -> np.ndarray:
    """Pooled quantile edges of a state variable over both parts (split-free); duplicate edges
    (a night of zero radiation) merged."""
    v = np.concatenate(parts)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return np.zeros(1)
    return np.unique(np.quantile(v, np.linspace(0.0, 1.0, STATE_BINS + 1)))


def _units(times: list[np.ndarray], rs: list[np.ndarray],
           states: list[dict[str, np.ndarray]] | None, clock: SolarClock,
           ) -> tuple[list[np.ndarray], list[tuple[str, float, float]]]:
    """Day units of each part (days of ``clock``), clock columns then state columns; days with
    less than half the clock bins are left out. Also (variable, lo, hi) per state column."""
    cols: list[tuple[str, float, float]] = []
    out = []
    edges = {}
    if states:
        edges = {k: _edges([s[k] for s in states]) for k in states[0]}
        for k, e in edges.items():
            cols += [(k, float(e[j]), float(e[j + 1])) for j in range(len(e) - 1)]
    for i, (time, r) in enumerate(zip(times, rs, strict=True)):
        sec = clock.seconds(time)
        _, day = np.unique(sec // DAY_S, return_inverse=True)
        u = _clock_units(day, sec, r)
        keep = np.isfinite(u).sum(axis=1) >= u.shape[1] // 2
        if states and edges:  # edges only come with states
            step = float(np.median(np.diff(sec))) if len(sec) > 1 else BIN_S
            min_n = max(int(np.ceil(BIN_S / max(step, 1.0))), 1)
            u = np.hstack([u] + [_state_units(day, states[i][k], e, r, min_n)
                                 for k, e in edges.items() if len(e) > 1])
        out.append(u[keep])
    return out, cols


def _welch_t(assign: np.ndarray, v: np.ndarray, fin: np.ndarray) -> np.ndarray:
    """Welch t per column (held-out minus calibration) for each row of the 0/1 day assignment
    ``assign`` (splits, days) of the day-unit values ``v`` (zeros where missing, ``fin`` 0/1)."""
    def moments(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n, s, q = a @ fin, a @ v, a @ (v * v)
        mean = s / np.maximum(n, 1)
        var = (q - n * mean**2) / np.maximum(n - 1, 1)
        return n, mean, var
    n1, m1, v1 = moments(assign)
    n0, m0, v0 = moments(1.0 - assign)
    with np.errstate(all="ignore"):
        t = (m1 - m0) / np.sqrt(v1 / n1 + v0 / n0)
    return np.where((n1 >= MIN_DAYS) & (n0 >= MIN_DAYS) & np.isfinite(t), t, 0.0)


def _splits(nd: int, nh: int) -> np.ndarray:
    """0/1 held-out assignments of the null, the observed one (first ``nh`` days) first."""
    obs = np.zeros((1, nd))
    obs[0, :nh] = 1.0
    if comb(nd, nh) <= PERM_MAX:
        assign = np.zeros((comb(nd, nh), nd))
        for i, c in enumerate(combinations(range(nd), nh)):
            assign[i, list(c)] = 1.0
        return np.vstack([obs, assign])
    rng = np.random.default_rng(0)
    return np.vstack([obs, (np.argsort(rng.random((PERM_MAX, nd)), axis=1) < nh).astype(float)])


def day_test(time_h: np.ndarray, r_h: np.ndarray, time_c: np.ndarray, r_c: np.ndarray,
             alpha: float | None = None, state_h: dict[str, np.ndarray] | None = None,
             state_c: dict[str, np.ndarray] | None = None,
             clock: SolarClock = UTC_CLOCK) -> DayTest:
    """Has the held-out residual ``r_h`` a feature the calibration part's ``r_c`` has not,
    beyond what days differ by: at a time of day (each day's half-hour profile minus its ±2 h
    running median) or, given ``state_h``/``state_c`` (``controller_state`` of each part), in a
    band of the plant's state (each day's state-bin means minus their median)? Welch t per
    column between the two parts' days, max |t| over all columns against its null from swapping
    whole days (all splits or ``PERM_MAX``; the observed split counts once more in the
    drawn case). Nothing in it scales with the size of the residual. Days and time of day are
    those of ``clock`` (the site's local solar time, ``drivers.clock_of``; UTC without one)."""
    alpha = UNEXPLAINED_ALPHA if alpha is None else alpha
    states = [state_h, state_c] if state_h is not None and state_c is not None else None
    (uh, uc), cols = _units([time_h, time_c], [r_h, r_c], states, clock)
    nh, nc = len(uh), len(uc)
    if nh < 2 or nc < 2:
        return DayTest(1.0, 0.0, [], [], nh, nc)
    u = np.vstack([uh, uc])
    fin = np.isfinite(u).astype(float)
    v = np.where(fin > 0, u, 0.0)
    assign = _splits(nh + nc, nh)
    t_all = _welch_t(assign, v, fin)
    t_obs = t_all[0]
    null = np.abs(t_all[1:] if comb(nh + nc, nh) <= PERM_MAX else t_all).max(axis=1)
    t_max = float(np.abs(t_obs).max())
    p = float(np.mean(null >= t_max - 1e-12))
    crit = float(np.quantile(null, 1.0 - alpha))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an empty column: NaN, never named
        d = np.nanmean(uh, axis=0) - np.nanmean(uc, axis=0)
    hit = np.flatnonzero(np.abs(t_obs) > crit)
    nb = int(DAY_S // BIN_S)
    bins = [int(j) for j in hit if j < nb]
    state = [StateBin(*cols[j - nb], float(d[j])) for j in hit if j >= nb]
    return DayTest(p, t_max, bins, [float(d[j]) for j in bins], nh, nc, state)

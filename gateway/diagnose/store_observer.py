"""The lumped heat store's temperature from measurements (structure.py, docs/effects.md "Base
structure").

T_s is never measured, so wherever a run starts from a measured air temperature the store
starts from an *observer*: the store equation of ``Structured.advance``

    C_s dT_s/dt = a_s I_glob + h_s (T_in - T_s) + k_s (T_out - T_s)

driven by the *measured* (true, sensor terms removed) air temperature instead of the simulated
one. With the inputs held over each step (zero-order hold) one step is exact:

    T_s[t+1] = λ T_s[t] + (1 - λ) u[t],   λ = exp(-(h_s + k_s) Δ / C_s),
    u[t] = (a_s I_glob[t] + h_s T_in[t+1] + k_s T_out[t]) / (h_s + k_s)

(the store's step from t to t+1 sees the air at t+1, as in ``advance``). :func:`observe` runs
it for every candidate at once, causal (T_s[t] uses readings up to t only), from equilibrium
with the first inputs; gaps in the drivers are bridged linearly for it (never scored).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def gaps_bridged(v: np.ndarray) -> np.ndarray:
    """Gaps bridged linearly (only to drive the store observer, never scored)."""
    ok = np.isfinite(v)
    if ok.all() or not ok.any():
        return np.nan_to_num(v)
    idx = np.arange(len(v))
    return np.interp(idx, idx[ok], v[ok])


def observe(q: Mapping[str, np.ndarray], x: Mapping[str, np.ndarray], ta: np.ndarray,
            dt: float) -> np.ndarray:
    """Store temperature T_s (P, T) [°C] (module docstring): ``q`` the parameters in force
    (columns (P, 1): h_store, k_store [W m-2 K-1], c_store [J m-2 K-1], a_store [-]), ``x`` the
    drivers (i_glob, t_out), ``ta`` the true air temperature (1 or P, T) behind the gap-bridged
    readings, ``dt`` the step Δ [s]. Exact for the zero-order-hold inputs; a Python loop over
    blocks of samples, not over samples."""
    n = len(x["t_in"])
    n_p = next(iter(q.values())).shape[0]
    ta = np.broadcast_to(ta, (n_p, n))
    # the store's step from t to t+1 sees the air at t+1 (as in ``advance``)
    ta = np.concatenate([ta[:, 1:], ta[:, -1:]], axis=1)
    h, k, cs = q["h_store"], q["k_store"], q["c_store"]
    s = np.maximum(h + k, 1e-9)
    u = (q["a_store"] * gaps_bridged(x["i_glob"])[None, :] + h * ta
         + k * gaps_bridged(x["t_out"])[None, :]) / s
    u = np.broadcast_to(u, (n_p, n))
    rate = s * dt / cs  # -ln λ per sample (P, 1)
    lam = np.exp(-rate)
    # blocks of L samples with λ^-L ≤ e^30, so the scaled cumulative sums stay exact
    L = int(max(1, min(n, np.floor(30.0 / float(np.max(rate))))))
    nb = -(-n // L)
    pad = nb * L - n
    up = np.concatenate([u, np.repeat(u[:, -1:], pad, axis=1)], axis=1).reshape(n_p, nb, L)
    j = np.arange(L)[None, :]
    scale = np.exp(rate * j)  # λ^-j (P, L)
    # y[b+i] = λ^i y[b] + (1-λ) λ^(i-1) Σ_{j<i} λ^-j u[b+j]
    cs_ = np.cumsum(up * scale[:, None, :], axis=2)  # Σ_{j<=i}
    part = np.concatenate([np.zeros((n_p, nb, 1)), cs_[:, :, :-1]], axis=2)  # Σ_{j<i}
    lam_i = np.exp(-rate * j)  # λ^i
    forced = (1.0 - lam)[:, :, None] * (lam_i / lam)[:, None, :] * part
    y_end = (1.0 - lam) * np.exp(-rate * (L - 1)) * cs_[:, :, -1]  # forced part at b+L
    out = np.empty((n_p, nb, L))
    y = u[:, 0].copy()  # start at equilibrium with the first inputs
    lam_l = np.exp(-rate * L)[:, 0]
    for b in range(nb):
        out[:, b, :] = lam_i * y[:, None] + forced[:, b, :]
        y = lam_l * y + y_end[:, b]
    return out.reshape(n_p, nb * L)[:, :n]

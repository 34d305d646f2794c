"""A heat store added from τ and coupled to the air: water barrels or tanks, a concrete floor
or wall (issue 10, docs/effects.md "An added heat store").

The library's ``thermal_mass`` multiplies the air node's capacity: right for mass that follows
the air within a model step (more crop, a frame). Water in containers is a *slow* store with its
own temperature T_w, exchanging heat with the air through its surface:

    C_w dT_w/dt = h_w (T_in - T_w)                         (store, as the base's, structure.py)
    Q_w         = h_w (T_w - T_in)                         (into the air, W m-2 of floor)

from τ on, T_w(τ) = T_in(τ) (filled at the air's temperature); before τ there is no store (Q_w
= 0). C_w [J m-2 K-1] is the effect's amplitude (4186 J kg-1 K-1 per kg of water per m² of
floor). The coupling h_w [W m-2 K-1] (film coefficient of the wetted surface × that surface per
m² of floor) enters through the store's time constant t_w = C_w / h_w [s], a third parameter
refitted with the base by Levenberg–Marquardt; the τ scan holds it at its start. With t_w held,
T_w is a low-pass of the air that does not depend on C_w, so Q_w is linear in the amplitude and
the scan's secant steps (fit.scan_tau) reach it (with h_w held instead, the response saturates
in C_w: two secant steps found a fifth of a 7 h store's capacity). t_w decides what the store
looks like: minutes, extra capacity (what ``thermal_mass`` already says); hours, a lagging
exchange that pulls the day's swing towards the store's slowly moving temperature.

The step is the model's split step (structure.Structured.advance): the air with T_w frozen,
then the store with the new air. The coupling the air sees over a step is the heat the store
can take in that step, ``h_eff = C_w (1 - λ) / dt`` with ``λ = exp(-h_w dt / C_w)``: h_w for a
slow store, C_w / dt (a capacity, lagged one step) for a fast one, 0 exactly at C_w = 0 (the
base model). Vectorised over candidate rows like the rest of the diagnosis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gateway.diagnose.store_observer import gaps_bridged
from gateway.diagnose.structure import INDEX, on
from gateway.model.terms import ALWAYS, Index, Parameter

if TYPE_CHECKING:
    from gateway.diagnose.structure import Structured

DAY_CORNER_S = 86400.0 / (2.0 * np.pi)
"""1/ω of the daily cycle, 3.8 h: a store of this time constant is half capacity, half
conductance to the day's swing."""
TIME_CONSTANT = Parameter("t_added", "s", 600.0, 2 * 86400.0, DAY_CORNER_S, None, ALWAYS,
                          "time constant C_w / h_w of the added store")
"""Bounds: two model steps (a store faster than that is a capacity) to two days (slower, it is
a fixed temperature over a two-week record). Start at the daily cycle's corner 1/ω = 3.8 h: water
in containers runs from minutes (a thin layer) over hours (20 cm tubes: 131 kJ K-1 per m of
length over 0.63 m² at 3–8 W m-2 K-1, 7–19 h) to days (200 L barrels: 0.9 MJ K-1 over 1.8 m²,
18–48 h); 1/ω is equidistant (in log) from the two regimes the scan must reach."""
MAX_RATE = 5.0
"""Largest dt / t_w the store observer resolves (λ ≥ e^-5; with t_w ≥ 600 s it binds only for
steps over 50 min): a faster store follows the air within 1 % per step; the observer's block
sums need λ^-L ≤ e^30 (store_observer.observe)."""


@dataclass(frozen=True)
class AddedStore:
    """The model part of an added heat store: its parameters (C_w amplitude, h_w, τ), its
    coupling to the air, its step and its observer (module docstring)."""

    name: str
    amp: Parameter
    tau: Parameter
    time_constant: Parameter = TIME_CONSTANT

    @property
    def parameters(self) -> tuple[Parameter, Parameter, Parameter]:
        return (self.amp, self.time_constant, self.tau)

    def _lam(self, p, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(λ, C_w) per row: λ = exp(-dt / t_w) = exp(-h_w dt / C_w)."""
        lam = np.exp(-dt / p[self.time_constant.name])
        return lam, np.maximum(p[self.amp.name], 0.0)

    def coefficients(self, p, x, tw, t: Index, dt: float, unit: float):
        """(g, s) of Q_w = h_eff (T_w - T_in) in the model's units (``unit``, III.24), T_w
        frozen over the step: h_eff = C_w (1 - λ) / dt from τ, else 0."""
        lam, c = self._lam(p, dt)
        h = unit * c * (1.0 - lam) / dt * on(p, x, t, self.tau.name)
        return h * tw, h

    def step(self, p, x, tw, ta_new, t: Index, dt: float) -> np.ndarray:
        """T_w after the step: λ T_w + (1 - λ) T_in(new) from τ; before it, the air's."""
        lam, _ = self._lam(p, dt)
        return np.where(on(p, x, t, self.tau.name) > 0, lam * tw + (1.0 - lam) * ta_new, ta_new)

    def observer(self, model: Structured, p, x, dt: float) -> np.ndarray:
        """T_w (P, T) driven by the measured air temperature (causal, as the base store's
        observer): the air's reading before τ; from the first sample k at or after τ,
        T_w(t) = F(t) - λ^(t-k) (F(k) - T_in(k)), where F is the same filter run from the
        first sample (the base store's exact block filter with k_s = a_s = 0, h_s = 1,
        C_s = t_w: the filter depends on t_w only)."""
        n = len(x["t_in"])
        c = np.maximum(p[self.time_constant.name], dt / MAX_RATE)
        one = np.ones_like(c)
        fake = dict(p) | {"c_store": c, "h_store": one, "k_store": 0 * one, "a_store": 0 * one}
        f = model.observer(fake, x, dt)  # (P, T)
        idx = slice(0, n)
        ta = np.broadcast_to(model.true_state(p, x, gaps_bridged(x["t_in"])[None, :], idx), f.shape)
        k = np.searchsorted(x[INDEX], p[self.tau.name][:, 0], side="left")  # (P,)
        kk = np.minimum(k, n - 1)[:, None]
        rows = np.arange(f.shape[0])[:, None]
        lag = np.arange(n)[None, :] - k[:, None]
        gap = f[rows, kk] - ta[rows, kk]  # (P, 1)
        decay = np.exp(-(dt / c) * np.maximum(lag, 0))
        return np.where(lag >= 0, f - decay * gap, ta)

    def flux(self, model: Structured, theta: np.ndarray, x, dt: float) -> np.ndarray:
        """Q_w [W m-2 of floor] over the record for one parameter vector, the store from its
        observer (the finding's trace)."""
        p = model.columns(np.atleast_2d(theta))
        n = len(x["t_in"])
        tw = self.observer(model, p, x, dt)
        ta = model.true_state(p, x, gaps_bridged(x["t_in"])[None, :], slice(0, n))
        g, s = self.coefficients(p, x, tw, slice(0, n), dt, 1.0)
        return (g - s * ta)[0]

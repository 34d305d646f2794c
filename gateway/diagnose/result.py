"""What a diagnosis returns: findings with their evidence, held-out figures, the JSON form."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gateway.diagnose import residuals as res
from gateway.diagnose.effects import Effect, part_as
from gateway.diagnose.heat_store import AddedStore
from gateway.diagnose.judge import Verdict
from gateway.diagnose.structure import INDEX, Modulation, Structured, model_unit, physical_capacity
from gateway.greenhouse import Greenhouse
from gateway.model.drivers import clock_of
from gateway.model.model import Model
from gateway.model.terms import SensorTerm
from gateway.series import Series


@dataclass
class Finding:
    """One accepted effect with its fitted parameters and the evidence for it."""

    effect: Effect
    tau: float  # [s since the first sample]
    start: str | None  # ISO UTC, None = before the data
    amplitude: float
    summary: str
    evidence: str
    mae_before: float
    mae_after: float
    delta_bic: float
    trace: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """The fitted effect over the record: flux [W m-2 of floor], factor [-] or offset [K]."""
    trace_unit: str = ""
    heating_rate: float | None = None
    """A heat flux's warming of the air node before losses [K h-1]: P / (m_cap C_phys). The
    temperatures fix this, not P: the base is scale-free (docs/effects.md, "What a flux
    amplitude's W m-2 are"), so P is in the fitted capacity's scale."""

    def to_json(self) -> dict:
        e = self.effect
        out: dict[str, object] = {
            "effect": e.name,
            "start": self.start,
            "params": {e.amp_name: self.amplitude, "unit": e.unit},
            "summary": self.summary,
            "evidence": self.evidence,
        }
        if self.heating_rate is not None:
            out["heating_rate_K_per_h"] = self.heating_rate
        return out


def heating_rate(e: Effect, model: Model, theta: np.ndarray, gh: Greenhouse
                 ) -> tuple[float, float] | None:
    """(warming rate [K h-1], capacity factor m_cap [-]) of a heat-input effect's fitted P
    [W m-2]: P / (m_cap C_phys) (III.24), what the temperatures identify; None for other
    effects."""
    if e.unit != "W m-2" or e.kind != "flux":
        return None
    m_cap = float(theta[model.index("m_cap")]) if "m_cap" in model.names else 1.0
    amp = float(theta[model.index(e.amp_name)])
    return amp * 3600.0 / (m_cap * physical_capacity(gh)), m_cap


@dataclass
class Diagnosis:
    """Everything the report and the JSON need."""

    model: Model  # final composed model
    theta: np.ndarray  # final parameters fitted on all data (for plots and findings)
    base_model: Model
    base_theta: np.ndarray
    findings: list[Finding]
    rejected: list[dict]
    before: dict
    after: dict
    persistence: dict
    unexplained: bool
    signature: str
    split_index: int
    blocks: list[tuple[int, int]]
    time: np.ndarray
    measured: np.ndarray
    pred_before: dict[str, np.ndarray]  # "free_run", "one_step" over the held-out part
    pred_after: dict[str, np.ndarray]
    analysis_before: dict = field(default_factory=dict)
    analysis_after: dict = field(default_factory=dict)
    seconds: float = 0.0
    structure: list[dict] = field(default_factory=list)
    """The base structure choices on the calibration part, in order tried."""
    trials: list[dict] = field(default_factory=list)
    """Every candidate the judge saw: round, effect, its statistics and the decision."""


def make_finding(e: Effect, model: Model, theta: np.ndarray, series: Series, pred_before: dict,
                 verdict: Verdict, dbic: float, x: dict, s: int, gh: Greenhouse) -> Finding:
    """The finding of ``e`` as fitted on all data (``theta``), with its evidence."""
    tau = float(theta[model.index(e.tau_name)])
    amp = float(theta[model.index(e.amp_name)])
    stamp = series.time[0] + np.timedelta64(int(round(tau)), "s")
    start = None if tau <= 0 else str(stamp) + "Z"
    when = f"from {str(stamp)[:16].replace('T', ' ')} UTC" if start else "throughout the data"
    summary = f"{e.describe(amp)} {when}"
    rate = heating_rate(e, model, theta, gh)
    if rate is not None:
        summary += (f" (warms the air {rate[0]:.2g} K h-1 before losses; the W m-2 are at the "
                    f"fitted heat capacity, {rate[1]:.2f} x the air's)")
    r = x["t_in"][s:] - pred_before["free_run"]
    t_c = series.time[0] + x["_index"].astype("timedelta64[s]")
    sig = res.short_signature(t_c[s:], r, x, s, float(x["_index"][1] - x["_index"][0]),
                              clock_of(gh))
    evidence = (f"{verdict.why}; ΔBIC {dbic:.0f} on all data; residual before it: {sig}; "
                f"expected signature: {e.signature}")
    return Finding(e, tau, start, amp, summary, evidence, verdict.mae_before,
                   verdict.mae_after, dbic, heating_rate=None if rate is None else rate[0])


def traces(findings: list[Finding], model: Structured, theta: np.ndarray, x, gh: Greenhouse,
           duration: float) -> None:
    """Each finding over the record: flux (physical W m-2; an added store's exchange with the
    air), factor (-) or sensor offset (K)."""
    n = len(x["t_in"])
    idx = slice(0, n)
    p = {k: v[:, 0] for k, v in model.columns(theta[None, :]).items()}
    fluxes = model.fluxes(theta, x, x["t_in"])
    for f in findings:
        part = f.effect.build(model, gh, duration)
        if f.effect.kind == "sensor":
            sensor = part_as(f.effect, part, SensorTerm)
            f.trace = np.broadcast_to(sensor.offset(p, x, idx), (n,)).copy()
            f.trace_unit = "K"
        elif f.effect.kind == "modulation":
            mod = part_as(f.effect, part, Modulation)
            f.trace = np.broadcast_to(mod.factor(p, x, idx), (n,)).copy()
            f.trace_unit = "factor"
        elif f.effect.kind == "store":
            store = part_as(f.effect, part, AddedStore)
            f.trace = store.flux(model, theta, x, float(x[INDEX][1] - x[INDEX][0]))
            f.trace_unit = "W m-2"
        else:
            f.trace = fluxes[part.name] / model_unit(model, gh)
            f.trace_unit = "W m-2"


def to_json(d: Diagnosis) -> dict:
    """The ``--json`` object: findings, before/after held-out metrics, unexplained."""
    def strip(m: dict) -> dict:
        return {k: (None if v is None else {q: v[q] for q in ("mae", "rmse", "maxae", "r2", "ef")})
                for k, v in m.items()}

    return {
        "findings": [f.to_json() for f in d.findings],
        "before": strip(d.before),
        "after": strip(d.after),
        "persistence": strip(d.persistence),
        "unexplained": d.unexplained,
        "signature": d.signature,
        "base_structure": d.structure,
        "rejected": d.rejected,
        "heldout": {"start": str(d.time[d.split_index]) + "Z", "end": str(d.time[-1]) + "Z",
                    "blocks": len(d.blocks)},
        "seconds": d.seconds,
    }

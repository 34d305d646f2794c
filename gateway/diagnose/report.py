"""``report.md`` and PNG plots of a diagnosis (matplotlib, Agg backend)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from gateway.diagnose.result import Diagnosis

MODES = (("free_run", "free run"), ("one_step", "one-step"))


def write_report(d: Diagnosis, out: str | Path, source: str,
                 notes: Sequence[Mapping[str, str]] = (), hint: str | None = None) -> Path:
    """Write ``report.md`` and the PNGs into ``out``; return the markdown path. ``notes``: the
    run's notes on its data ({code, level, message}, gateway/cli/notes.py), a "Notes" section
    ahead of the figures when there are any. ``hint``: which model the online estimator should
    run (gateway/cli/diagnose.py ``live_model_hint``), a line under the findings."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _plot_residuals(d, out / "residual.png")
    _plot_hours(d, out / "hour_of_day.png")
    _plot_effects(d, out / "effects.png")
    lines = [f"# Diagnosis of {source}", "",
             f"Model `{d.model.name}`; calibration part up to {str(d.time[d.split_index])[:16]} UTC, "
             f"held-out part after it ({len(d.blocks)} blocks, free runs restarted at each block). "
             f"{d.seconds:.1f} s.", "", *notes_section(notes),
             *([f"**Hint:** {hint}.", ""] if hint else []),
             "## Base structure (calibration part only)", "",
             "Before any effect is searched, the thesis model gets an effective heat capacity and "
             "optional parts, each kept only if BIC on the calibration part falls "
             "(docs/effects.md):", ""]
    for st in d.structure:
        verdict = "kept" if st["kept"] else "not kept"
        lines.append(f"- {st['structure']}: {verdict} (ΔBIC {st['delta_bic']:+.1f}, shooting MSE "
                     f"{st['mse']:.3f} K²); {st['detail']}")
    lines += ["", "Base parameters: " + ", ".join(
        f"`{n}` = {v:.4g}" for n, v in zip(d.base_model.names, d.base_theta, strict=True)), "",
        "## Findings", ""]
    if not d.findings:
        lines.append("No library effect improved the held-out error significantly.")
    for i, f in enumerate(d.findings, 1):
        lines += [f"{i}. **{f.effect.name}**: {f.summary}.",
                  f"   - parameters: `{f.effect.amp_name}` = {f.amplitude:.4g} {f.effect.unit}, "
                  f"start {f.start or 'before the data'}",
                  f"   - evidence: {f.evidence}", ""]
    if d.rejected:
        lines += ["", "Tried and rejected:", ""]
        lines += [f"- {r['effect']}: {r['reason']}" for r in d.rejected]
    lines += ["", "## Held-out error, before and after (with persistence)", "",
              "| prediction | metric | persistence | before | after |", "| --- | --- | --- | --- | --- |"]
    for key, label in MODES:
        for q in ("mae", "rmse", "maxae", "r2", "ef"):
            vals = [d.persistence[key], d.before[key], d.after[key]]
            cells = ["–" if v is None else f"{v[q]:.3f}" for v in vals]
            lines.append(f"| {label} | {q} | " + " | ".join(cells) + " |")
    lines += ["", "## Residual after the diagnosis", "",
              ("**Unexplained:** the residual keeps a structure no library effect explains. "
               if d.unexplained else "No unexplained structure detected. ") + d.signature, "",
              "![residual](residual.png)", "", "![hour of day](hour_of_day.png)", "",
              "![effects](effects.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def notes_section(notes: Sequence[Mapping[str, str]]) -> list[str]:
    """The "Notes" section: each note's code and message, warnings marked; none without
    notes."""
    if not notes:
        return []
    lines = ["## Notes", "", "Read the figures below with these notes on the data "
             "(docs/data-format.md, \"Notes\"):", ""]
    for n in notes:
        tag = "**warning** " if n.get("level") == "warning" else ""
        lines.append(f"- {tag}`{n['code']}`: {n['message']}")
    return [*lines, ""]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_residuals(d: Diagnosis, path: Path) -> None:
    plt = _plt()
    s = d.split_index
    t = d.time[s:].astype("datetime64[m]").astype(object)
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(t, d.measured[s:], "k", lw=0.8, label="measured")
    ax[0].plot(t, d.pred_before["free_run"], lw=0.8, label="model before")
    ax[0].plot(t, d.pred_after["free_run"], lw=0.8, label="model after")
    ax[0].set_ylabel("T_in [°C]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, d.measured[s:] - d.pred_before["free_run"], lw=0.7, label="residual before")
    ax[1].plot(t, d.measured[s:] - d.pred_after["free_run"], lw=0.7, label="residual after")
    ax[1].axhline(0, color="grey", lw=0.5)
    ax[1].set_ylabel("measured − free run [K]")
    ax[1].legend(loc="upper right", fontsize=8)
    for a, _ in d.blocks:
        ax[1].axvline(d.time[a].astype("datetime64[m]").astype(object), color="grey", lw=0.4, ls=":")
    fig.suptitle("Held-out part: free runs restarted at each block (dotted)")
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _plot_hours(d: Diagnosis, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    h = np.arange(24)
    ax.plot(h, d.analysis_before["hour_profile"], "o-", label="before")
    ax.plot(h, d.analysis_after["hour_profile"], "o-", label="after")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlabel(f"hour of day [{d.analysis_after.get('clock', 'UTC')}]")
    ax.set_ylabel("mean residual [K]")
    ax.set_title("Held-out free-run residual by hour of day")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _plot_effects(d: Diagnosis, path: Path) -> None:
    """Each finding's flux [W m-2 of the model] or sensor offset [K] over the whole record."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4))
    t = d.time.astype("datetime64[m]").astype(object)
    if not d.findings:
        ax.text(0.5, 0.5, "no effect found", ha="center", va="center", transform=ax.transAxes)
    for f in d.findings:
        ax.plot(t, f.trace, lw=0.8, label=f"{f.effect.name} ({f.trace_unit})")
    ax.axvline(d.time[d.split_index].astype("datetime64[m]").astype(object), color="k", lw=0.6,
               ls="--", label="start of held-out part")
    ax.set_ylabel("effect")
    ax.set_title("Fitted effects over time (fit on all data)")
    ax.legend(fontsize=8)
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)

"""PNG figures for people who would rather look than read (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from gateway.estimate.replay import ReplayResult


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_formats() -> list[str]:
    """The file name endings (without the dot) a figure can be saved as: matplotlib's own list."""
    from matplotlib.backend_bases import FigureCanvasBase

    return sorted(FigureCanvasBase.get_supported_filetypes())


def plot_replay(result: ReplayResult, path: str | Path, title: str = "") -> None:
    """Measured vs predicted T_in, the one-step residual, and each parameter inside its hard box."""
    plt = _pyplot()
    model = result.model
    names = model.names
    lo, hi = model.bounds(result.gh)
    t = result.time.astype("datetime64[s]").astype("O")
    ncols = 2
    nrows_p = (len(names) + ncols - 1) // ncols
    fig = plt.figure(figsize=(12, 6 + 1.6 * nrows_p), layout="constrained")
    grid = fig.add_gridspec(3 + nrows_p, ncols, height_ratios=[2.2, 1.2, 1.2] + [1.0] * nrows_p)
    ax = fig.add_subplot(grid[0, :])
    ax.plot(t, result.measured, color="black", lw=0.9, label="measured")
    ax.plot(t, result.constant, color="tab:orange", lw=0.8, alpha=0.8, label="constant parameters")
    ax.plot(t, result.adaptive, color="tab:blue", lw=0.8, label="adaptive (one step ahead)")
    ax.set_ylabel("T_in [°C]")
    ax.legend(loc="upper right", fontsize=8, ncols=3)
    ax.set_title(title or f"{model.name}: online estimation replay")
    ax_r = fig.add_subplot(grid[1, :], sharex=ax)
    ax_r.plot(t, result.constant - result.measured, color="tab:orange", lw=0.6, alpha=0.7,
              label="constant")
    ax_r.plot(t, result.adaptive - result.measured, color="tab:blue", lw=0.6, label="adaptive")
    ax_r.axhline(0.0, color="black", lw=0.5)
    ax_r.set_ylabel("one-step\nresidual [K]")
    ax_r.legend(loc="upper right", fontsize=8, ncols=2)
    ax_h = fig.add_subplot(grid[2, :], sharex=ax)
    h = max(result.horizons) if result.horizons else None
    if h is not None:
        f = result.horizons[h]
        th = t[f["target"]] if len(f["target"]) else []
        ax_h.plot(th, f["persistence"] - f["measured"], color="tab:gray", lw=0.6, label="persistence")
        ax_h.plot(th, f["adaptive"] - f["measured"], color="tab:blue", lw=0.6, label="adaptive")
        ax_h.axhline(0.0, color="black", lw=0.5)
        ax_h.legend(loc="upper right", fontsize=8, ncols=2)
    ax_h.set_ylabel(f"{h}-min forecast\nresidual [K]")
    for j, name in enumerate(names):
        a = fig.add_subplot(grid[3 + j // ncols, j % ncols], sharex=ax)
        a.axhspan(lo[j], hi[j], color="tab:green", alpha=0.08)
        a.axhline(lo[j], color="tab:green", lw=0.6, ls="--")
        a.axhline(hi[j], color="tab:green", lw=0.6, ls="--")
        a.plot(t, result.theta[:, j], color="tab:blue", lw=0.8)
        a.axhline(result.theta0[j], color="tab:orange", lw=0.6, ls=":")
        unit = model.parameters[j].unit
        a.set_ylabel(f"{name}\n[{unit}]", fontsize=8)
        a.tick_params(labelsize=7)
        span = hi[j] - lo[j]
        a.set_ylim(lo[j] - 0.05 * span, hi[j] + 0.05 * span)
    import matplotlib.dates as mdates

    for a in fig.axes:
        locator = mdates.AutoDateLocator()
        a.xaxis.set_major_locator(locator)
        a.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))
        a.tick_params(axis="x", labelsize=7)
        a.xaxis.get_offset_text().set_visible(a is ax)  # the date once, under the top panel
    fig.savefig(path, dpi=90)
    plt.close(fig)


def finite_range(values: np.ndarray) -> tuple[float, float]:
    """(min, max) of the finite values, (0, 1) when none."""
    v = values[np.isfinite(values)]
    return (float(v.min()), float(v.max())) if v.size else (0.0, 1.0)

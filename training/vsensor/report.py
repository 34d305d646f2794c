"""The training report (thesis §IV.3.2.1): correlation circle, table 18, variance, validation.

- ``correlation_circle``: PCA of the standardised inputs *and* the target (the thesis's data
  analysis, figure 49); each variable's arrow is its correlation with PC1 and PC2.
- ``table18``: Pearson correlation of every input with the target heat loss Q_vent (and with
  the flow) on calm, windy and cloudy days and on all data, in table 18's layout. Day classes,
  per calendar day (UTC) of each file: *cloudy* when the day's radiation sum is below half the
  file's 90th-percentile day (relative to the site and season); of the others, *calm* when the
  day's mean wind is in the lowest third of all days, *windy* in the highest third.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from training.vsensor.dataset import Segment


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=90, metadata={"Software": None})
    _pyplot().close(fig)


def day_classes(segments: list[Segment]) -> list[np.ndarray]:
    """Per segment, a label per row: 'cloudy', 'calm', 'windy' or ''."""
    days = []
    for s in segments:
        d = s.time.astype("datetime64[D]")
        for day in np.unique(d):
            m = d == day
            days.append((np.nanmean(s.x["wind"][m]), np.nansum(np.maximum(s.x["i_glob"][m], 0))))
    winds = np.array([w for w, _ in days])
    lo, hi = np.nanpercentile(winds, [100 / 3, 200 / 3])
    out = []
    for s in segments:
        d = s.time.astype("datetime64[D]")
        labels = np.full(len(d), "", dtype=object)
        sums = {day: np.nansum(np.maximum(s.x["i_glob"][d == day], 0)) for day in np.unique(d)}
        ref = np.percentile(list(sums.values()), 90)
        for day in np.unique(d):
            m = d == day
            wind = np.nanmean(s.x["wind"][m])
            if sums[day] < 0.5 * ref:
                labels[m] = "cloudy"
            elif wind <= lo:
                labels[m] = "calm"
            elif wind >= hi:
                labels[m] = "windy"
        out.append(labels)
    return out


def table18(segments: list[Segment], names: list[str]) -> dict[str, dict[str, dict[str, float]]]:
    """{target: {class: {input: r}}} for targets 'q_vent' and 'flow'; classes calm, windy,
    cloudy, all. ``n`` under each class counts the rows."""
    labels = np.concatenate(day_classes(segments))
    u = np.concatenate([s.inputs for s in segments])
    targets = {"q_vent": np.concatenate([s.q_vent for s in segments]),
               "flow": np.concatenate([s.flow for s in segments])}
    out: dict[str, dict[str, dict[str, float]]] = {}
    for tname, y in targets.items():
        out[tname] = {}
        for cls in ("calm", "windy", "cloudy", "all"):
            m = np.isfinite(y) & np.all(np.isfinite(u), axis=1)
            if cls != "all":
                m &= labels == cls
            row = {"n": int(m.sum())}
            for j, n in enumerate(names):
                a, b = u[m, j], y[m]
                ok = a.std() > 0 and b.std() > 0 if m.sum() > 2 else False
                row[n] = float(np.corrcoef(a, b)[0, 1]) if ok else float("nan")
            out[tname][cls] = row
    return out


def table18_markdown(t: dict, names: list[str]) -> str:
    lines = []
    for tname, label in (("q_vent", "Q_vent [W m-2]"), ("flow", "G [m3 s-1]")):
        lines.append(f"| target | climate | days' rows | {' | '.join(names)} |")
        lines.append("|" + " --- |" * (3 + len(names)))
        for cls, row in t[tname].items():
            cells = " | ".join("" if not np.isfinite(row[n]) else f"{row[n]:.3f}" for n in names)
            lines.append(f"| {label} | {cls} | {row['n']} | {cells} |")
        lines.append("")
    return "\n".join(lines)


def correlation_circle(segments: list[Segment], names: list[str], path: Path) -> dict[str, list[float]]:
    """Figure 49: PC1–PC2 correlation circle of the inputs and the target Q_vent (PNG)."""
    plt = _pyplot()
    u = np.concatenate([s.inputs for s in segments])
    y = np.concatenate([s.q_vent for s in segments])
    data = np.column_stack([u, y])
    data = data[np.all(np.isfinite(data), axis=1)]
    z = (data - data.mean(axis=0)) / np.where(data.std(axis=0) > 0, data.std(axis=0), 1.0)
    vals, vecs = np.linalg.eigh(np.cov(z, rowvar=False))
    order = np.argsort(vals)[::-1]
    vals, vecs = vals[order], vecs[:, order]
    vecs = vecs * np.where(vecs[np.abs(vecs).argmax(axis=0), range(vecs.shape[1])] < 0, -1, 1)
    load = vecs[:, :2] * np.sqrt(np.maximum(vals[:2], 0))
    share = vals / vals.sum()
    labels = [*names, "Q_vent (target)"]
    fig, ax = plt.subplots(figsize=(6.4, 6.4), layout="constrained")
    ax.add_patch(plt.Circle((0, 0), 1.0, fill=False, color="grey", lw=0.8))
    for (a, b), lab in zip(load, labels, strict=True):
        color = "tab:red" if lab.startswith("Q_vent") else "tab:blue"
        ax.annotate("", xy=(a, b), xytext=(0, 0), arrowprops={"arrowstyle": "->", "color": color})
        ax.text(a * 1.07, b * 1.07, lab, fontsize=8, ha="center", color=color)
    ax.axhline(0, color="grey", lw=0.5)
    ax.axvline(0, color="grey", lw=0.5)
    ax.set_xlim(-1.15, 1.15)
    ax.set_ylim(-1.15, 1.15)
    ax.set_aspect("equal")
    ax.set_xlabel(f"PC1 ({100 * share[0]:.1f} %)")
    ax.set_ylabel(f"PC2 ({100 * share[1]:.1f} %)")
    ax.set_title("Correlation circle: inputs and target (thesis fig. 49)")
    _save(fig, path)
    return {lab: [float(a), float(b)] for (a, b), lab in zip(load, labels, strict=True)}


def variance_plot(share: np.ndarray, kept: int, path: Path) -> None:
    """Figure 50: variance share of each component of the inputs, the kept ones highlighted."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.6), layout="constrained")
    idx = np.arange(1, len(share) + 1)
    ax.bar(idx, 100 * share, color=["tab:blue" if i <= kept else "lightgrey" for i in idx])
    ax.plot(idx, 100 * np.cumsum(share), "o-", color="black", lw=0.8, label="cumulative")
    ax.axhline(90, color="tab:red", lw=0.6, ls="--", label="90 %")
    ax.set_xlabel("principal component")
    ax.set_ylabel("variance [%]")
    ax.set_title(f"{kept} components keep {100 * np.sum(share[:kept]):.1f} % (thesis fig. 50)")
    ax.legend(fontsize=8)
    _save(fig, path)


def validation_plot(segments: list[Segment], sims: dict[str, list[np.ndarray]], cuts: list[int],
                    path: Path, show: int = 3) -> None:
    """Figure 53: closed-loop flow vs the explicit flow on the validation quarter of a few files."""
    plt = _pyplot()
    picks = sorted(range(len(segments)), key=lambda i: -np.nanstd(segments[i].flow))[:show]
    fig, axes = plt.subplots(len(picks), 1, figsize=(10, 2.6 * len(picks)), layout="constrained")
    for ax, i in zip(np.atleast_1d(axes), picks, strict=True):
        s, c = segments[i], cuts[i]
        t = s.time[c:].astype("O")
        ax.plot(t, s.flow[c:], color="black", lw=0.9, label="explicit (vents)")
        for name, color in (("pca_narx", "tab:blue"), ("narx_no_pca", "tab:green"),
                            ("linear_arx", "tab:orange")):
            if name in sims:
                ax.plot(t, sims[name][i][c:], color=color, lw=0.7, label=name)
        ax.set_ylabel("G [m3 s-1]")
        ax.set_title(Path(s.source).stem, fontsize=9)
        ax.legend(fontsize=7, ncols=4, loc="upper right")
    _save(fig, path)

"""The model card (Markdown) written beside every trained sensor: what it reads, what it was
trained on, how well it did, where it must not be trusted, and the training report."""

from __future__ import annotations

from pathlib import Path

from training.vsensor.report import table18_markdown


def _m(m: dict) -> str:
    pct = "" if m.get("mae_pct_range") is None else f"{m['mae_pct_range']:.2f}"
    return f"{m['mae']:.3f} | {m['rmse']:.3f} | {m['maxae']:.2f} | {m['r2']:.3f} | {pct}"


def train_command(out: Path, meta: dict, held_files: tuple[str, ...] = ()) -> str:
    """The ``train`` command line that gives this model (file names only, from the metadata)."""
    st = meta["training_settings"]
    parts = ["python -m training.vsensor train --data", *(s["file"] for s in meta["sources"]),
             "--greenhouse", meta["greenhouse"]["name"], "--model", meta["model_kind"]]
    if meta.get("target_model_kind"):
        parts += ["--target-kind", meta["target_model_kind"]]
    for group, items in sorted((meta["online_overrides"] or {}).items()):
        parts += [f"--set {group}.{k}={v:g}" for k, v in sorted(items.items())]
    if meta["seed"]:
        parts.append(f"--seed {meta['seed']}")
    parts += [f"--hidden {','.join(map(str, st['hidden']))}", f"--epochs {st['epochs']}",
              f"--rounds {st['rounds']}", f"--pca-variance {st.get('pca_variance', 0.9):g}"]
    if st.get("round_lr"):
        parts.append(f"--round-lr {st['round_lr']:g}")
    if st.get("ensemble", 1) > 1:
        parts.append(f"--ensemble {st['ensemble']}")
    if st.get("net_seed", meta["seed"]) != meta["seed"]:
        parts.append(f"--net-seed {st['net_seed']}")
    if st.get("feedback", "member") != "member":
        parts.append(f"--feedback {st['feedback']}")
    if st.get("feedback_noise"):
        parts.append(f"--feedback-noise {st['feedback_noise']:g}")
    if st.get("high_flow_weight", 1.0) != 1.0:
        parts.append(f"--high-flow-weight {st['high_flow_weight']:g}")
    if st.get("target_transform", "identity") != "identity":
        parts.append(f"--target {st['target_transform']}")
    if st.get("extra_features"):
        parts.append(f"--extra-features {' '.join(st['extra_features'])}")
    if st.get("own_feedback"):
        parts.append("--own-feedback")
    if held_files:
        parts += ["--test", *held_files]
    return " ".join([*parts, "--out", out.name])


def model_card(out: Path, meta: dict, metrics: dict, t18: dict, circle: dict, names: list[str],
               nets: dict, rep_dir: Path, _pkg: str, heldout: str | None = None,
               held_files: tuple[str, ...] = ()) -> str:
    """The Markdown text of the card."""
    rel = rep_dir.as_posix() if not rep_dir.is_absolute() else rep_dir.name
    lines = (_inputs_and_structure(out, meta, names, nets)
             + _validation(out, meta, metrics, heldout, held_files)
             + _data(meta, t18, circle, names, rel))
    return "\n".join(lines)


def _target_kind_note(meta: dict) -> list[str]:
    """A paragraph when the target came from another model kind than the inputs."""
    kind, target = meta["model_kind"], meta.get("target_model_kind")
    if not target:
        return []
    return ["", f"**Target model kind: {target}** (inputs: {kind}). The sensor is fed by the "
            f"{kind} model only (what a live gateway of that kind runs); it learned, and is scored "
            f"against, the explicit flow of the **{target}** model with the vent signal, so scoring "
            f"a CSV needs the columns the {target} model reads, running it does not."]


def _inputs_and_structure(out: Path, meta: dict, names: list[str], nets: dict) -> list[str]:
    """Title, the inputs in their order, delays and the graph's structure."""
    pca = meta["pca"]
    gh = meta["greenhouse"]
    lines = [
        f"# Virtual ventilation sensor `{out.name}` (PCA-NARX, thesis §IV.3)",
        "",
        f"Estimates the natural-ventilation flow G [m3 s-1] of the greenhouse **{gh['name']}** (and its "
        "heat loss, III.32) without a vent signal, from the fluxes of the adaptive "
        f"**{meta['model_kind']}** model run without the vents, the wind and the inside–outside "
        "temperature and humidity differences. Runs with onnxruntime in `gateway/vsensor` "
        "(`VentSensor`, `python -m gateway vsensor`); see docs/vsensor.md.",
        *_target_kind_note(meta),
        "",
        "## Inputs (in this order; the runtime refuses a model whose list differs)",
        "",
        "| # | name | unit | low-pass τ [s] | training range | meaning |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for i, f in enumerate(meta["features"]):
        lo, hi = meta["training_ranges"][f["name"]]
        lines.append(f"| {i} | `{f['name']}` | {f['unit']} | {f['tau_s']:g} | {lo:.3g} … {hi:.3g} "
                     f"| {f['meaning']} |")
    lines += [
        "",
        f"Delays: inputs {meta['input_delays']}, outputs {meta['output_delays']} (closed loop: the "
        f"sensor's own past outputs), one step = {meta['step_s']:g} s. Target: {meta['target']}. "
        f"Flow range in training: {meta['flow_range'][0]:.3f} … {meta['flow_range'][1]:.3f} m3 s-1.",
        "",
        "## Structure",
        "",
        f"- Standardisation (centring, reduction) of the {len(names)} filtered inputs, then PCA: "
        f"**{pca['components']} components keep {100 * pca['variance_total']:.1f} %** of the variance "
        f"(shares {', '.join(f'{100 * v:.1f} %' for v in pca['variance_share'])}; thesis: 4 "
        "components, 93.8 %).",
        f"- NARX: {pca['components']} × {len(meta['input_delays'])} delayed components + "
        f"{len(meta['output_delays'])} past outputs → tanh layers "
        f"{'-'.join(map(str, nets['pca_narx'].hidden))} → flow (thesis: 30-50-20)"
        + (f"; an ensemble of {len(nets['pca_narx'].stacks)} such networks (seeds "
           f"{meta['training_settings']['net_seed']}…), their outputs averaged"
           + (", each fed its own past outputs (one output history per member, the runtime "
              "clips and averages the members' flows)." if nets['pca_narx'].histories > 1
              else " in the graph, each fed the ensemble's past outputs.")
           if len(nets['pca_narx'].stacks) > 1 else "."),
        "- One ONNX graph: standardisation, PCA and network; baselines beside it with the same "
        f"interface: `{out.stem}.narx_no_pca.onnx` (same network on the standardised inputs, no "
        f"PCA) and `{out.stem}.linear_arx.onnx` (linear ARX on the same inputs and delays).",
        "",
    ]
    return lines


def _target_words(target: str) -> str:
    """The settings sentence's part on what the networks learn (empty for the flow)."""
    if target == "identity":
        return ""
    if target == "mixed":
        return (", the even seeds' networks learning the flow G and the odd seeds' the effective "
                "opening G / D, averaged as flows in the graph")
    return f", the networks learning and feeding back {target}(G), inverted in the graph"


def _validation(out: Path, meta: dict, metrics: dict, heldout: str | None,
                held_files: tuple[str, ...]) -> list[str]:
    """Closed-loop validation, the training settings and command, the held-out files."""
    lines = [
        "## Validation (closed loop, the last quarter of every training file)",
        "",
        "| network | MAE [m3 s-1] | RMSE | MaxAE | R² | MAE % of range |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, m in metrics.items():
        lines.append(f"| {name} | {_m(m)} |")
    st = meta["training_settings"]
    lines += [
        "",
        f"Settings: hidden {'-'.join(map(str, st['hidden']))}, PCA to "
        f"{100 * st.get('pca_variance', 0.9):g} % of the variance, at most {st['epochs']} "
        f"series-parallel epochs, {st['rounds']} closed-loop rounds"
        + (f" (Adam step {st['round_lr']:g})" if st.get("round_lr") else "")
        + (" on the ensemble's feedback" if st.get("feedback", "member") != "member" else "")
        + (f", past outputs of the training rows offset by N(0, {st['feedback_noise']:g}) "
           "target standard deviations" if st.get("feedback_noise") else "")
        + (f", rows above the targets' 90th percentile weighing {st['high_flow_weight']:g}"
           if st.get("high_flow_weight", 1.0) != 1.0 else "")
        + _target_words(st.get("target_transform", "identity")) + ".",
        "",
    ]
    lines += [f"Trained with: `{train_command(out, meta, held_files)}` (paths in docs/vsensor.md).", ""]
    if heldout:
        lines += [
            "## Held-out files (`train --test`: closed loop through `VentSensor`, first hour left out)",
            "",
            "Scored after the fit against the explicit flow, the three networks in one run; never "
            "used to choose a setting.",
            "",
            heldout,
        ]
    else:
        lines += ["Figures on a site and season training never saw are in the README and "
                  "docs/vsensor.md.", ""]
    return lines


def _data(meta: dict, t18: dict, circle: dict, names: list[str], rel: str) -> list[str]:
    """The training files, the data analysis (correlation circle, table 18) and the limits."""
    gh = meta["greenhouse"]
    lines = [
        "## Training data",
        "",
        f"Greenhouse signature (another house is flagged, not trusted): {gh['signature']}.",
        f"Online estimator overrides: {meta['online_overrides'] or 'none (model and greenhouse defaults)'}; "
        f"seed {meta['seed']}; data fingerprint `{meta['data_fingerprint'][:16]}…`; serra {meta['version']}.",
        "The metadata's `code_probe` holds the fluxes, sky temperature and one-step T_in the model "
        "layer computed at training time on a fixed probe (gateway/vsensor/probe.py); the "
        "shipped-model test fails when the code no longer computes them: retrain then.",
        "",
        "| file | rows | sha256 |",
        "| --- | --- | --- |",
    ]
    for s in meta["sources"]:
        lines.append(f"| {s['file']} | {s['rows']} | `{s['sha256'][:16]}…` |")
    lines += [
        "",
        "## Data analysis (thesis §IV.3.2.1)",
        "",
        f"Correlation circle (PC1–PC2 of the inputs and the target): `{rel}/correlation_circle.png`; "
        f"variance per component: `{rel}/pca_variance.png`; closed-loop validation: `{rel}/validation.png`.",
        "",
        "Coordinates on PC1, PC2:",
        "",
        "| variable | PC1 | PC2 |",
        "| --- | --- | --- |",
    ]
    for name, (a, b) in circle.items():
        lines.append(f"| {name} | {a:.3f} | {b:.3f} |")
    lines += [
        "",
        "Pearson correlation of each input with the target (table 18's layout; day classes in "
        "training/vsensor/report.py):",
        "",
        table18_markdown(t18, names),
        "## Limits",
        "",
        "- Trained on simulated houses (the reference simulator and the two-node generator); a real "
        "house needs its own training data with vent openings (docs/vsensor.md, \"Retraining\").",
        "- Inputs outside the training ranges, missing inputs and another greenhouse are flagged "
        "(`VentEstimate.valid` False) and counted; the output is clamped to [0, the physical "
        "maximum of the house at that moment].",
        "",
    ]
    return lines

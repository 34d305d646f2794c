"""Rule lt (docs/effects.md, "The crop's transpiration as a base part"): the diagnosis's base
held-out free-run MAE on the tuning generators' 20 effect-free windows, with the crop's
vapour-deficit loss (gateway/diagnose/latent.py) not offered, or offered against the inside or
the outside vapour pressure. One JSON line per window; ``--compare`` tables two runs.

    .venv/bin/python tests/generality/latent_study.py off --out out/lt/off.jsonl     # ~8 min
    .venv/bin/python tests/generality/latent_study.py outside --out out/lt/outside.jsonl
    .venv/bin/python tests/generality/latent_study.py --compare out/lt/off.jsonl out/lt/outside.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import Case, case_series  # noqa: E402
from tests.generality.sky_study import WINDOWS  # noqa: E402


def run(variant: str, out: Path, generators: list[str], windows: list[str]) -> None:
    """Diagnose every effect-free window with the part as ``variant`` says; a line per window."""
    import gateway.diagnose.base as base
    from gateway.diagnose import diagnose

    base.OFFER_LATENT = variant != "off"
    base.LATENT_REFERENCE = variant if variant != "off" else base.LATENT_REFERENCE
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w") as f:
        for g in generators:
            for name in windows:
                c0 = time.process_time()
                with tempfile.TemporaryDirectory() as tmp:
                    _, gh, model, series = case_series(Case("diagnose", g, name, "none"), Path(tmp))
                    d = diagnose(series, gh, model)
                r = d.measured[d.split_index:] - d.pred_before["free_run"]
                bm = d.base_model
                row = {"generator": g, "window": name, "mae": float(np.nanmean(np.abs(r))),
                       "kept": [s["structure"] for s in d.structure
                                if s["kept"] and s["structure"] != "base"],
                       "findings": [f.effect.name for f in d.findings],
                       "c_vpd": float(d.base_theta[bm.index("c_vpd")]) if "c_vpd" in bm.names
                       else None, "cpu_s": time.process_time() - c0}
                f.write(json.dumps(row) + "\n")
                f.flush()
                print(f"{g} {name}: {row['mae']:.3f} K, kept {', '.join(row['kept']) or '-'}",
                      flush=True)


def compare(a_path: Path, b_path: Path) -> None:
    """The rule's step 1 on two runs: per-window table, generator and pooled means."""
    a = {(r["generator"], r["window"]): r for r in map(json.loads, a_path.open())}
    b = {(r["generator"], r["window"]): r for r in map(json.loads, b_path.open())}
    print("| generator | window | main [K] | candidate [K] | change | c_vpd | parts kept | "
          "findings main / candidate |\n|---|---|---|---|---|---|---|---|")
    pairs: dict[str, list[tuple[float, float]]] = {}
    for k in a:
        x, y = a[k]["mae"], b[k]["mae"]
        pairs.setdefault(k[0], []).append((x, y))
        cv = b[k]["c_vpd"]
        print(f"| {k[0]} | {k[1]} | {x:.3f} | {y:.3f} | {100 * (y / x - 1):+.1f} % | "
              f"{'-' if cv is None else f'{cv:.1f}'} | {', '.join(b[k]['kept']) or '-'} | "
              f"{', '.join(a[k]['findings']) or 'none'} / {', '.join(b[k]['findings']) or 'none'} |")
    every = [p for v in pairs.values() for p in v]
    for label, v in [*pairs.items(), ("pooled", every)]:
        mx, my = np.mean([p[0] for p in v]), np.mean([p[1] for p in v])
        print(f"{label}: {mx:.3f} -> {my:.3f} K ({100 * (my / mx - 1):+.1f} %)")
    print("windows worse by > 10 %:", sum(y > 1.1 * x for x, y in every))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("variant", nargs="?", choices=("off", "inside", "outside"))
    ap.add_argument("--out", type=Path, help="JSON lines, one per window")
    ap.add_argument("--generators", default="refsim,twonode", help="never the held-out one")
    ap.add_argument("--windows", default=",".join(WINDOWS))
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("MAIN", "CANDIDATE"))
    a = ap.parse_args(argv)
    if a.compare:
        compare(*a.compare)
        return 0
    if a.variant is None or a.out is None:
        ap.error("give a variant and --out (or --compare MAIN CANDIDATE)")
    if "vanthoor" in a.generators:
        ap.error("vanthoor is held out: not studied")
    run(a.variant, a.out, a.generators.split(","), a.windows.split(","))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

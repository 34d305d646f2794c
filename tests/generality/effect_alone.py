"""One library effect offered alone on dev cases: what the judge sees of it (docs/effects.md, "An
added heat store"). Per case: the base structure kept (and m_cap), the candidate's held-out cut,
p and the two folds' starts − truth from ``diagnose(..., library=(effect,))``, and with
``--fit`` its parameters fitted on all data after the base (``effect_fit.fit_effect``, as
tau_profile.py). Never the held-out generator.

    python tests/generality/effect_alone.py --effect heat_store_added [--fit] \\
        [refsim/autumn/thermal_mass ...]     # default: the six dev thermal_mass cases
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import Case, case_series  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402

DEFAULT = [f"{g}/{w}/thermal_mass" for g in ("refsim", "twonode")
           for w in ("autumn", "winter", "summer")]


def judged(label: str, effect: str) -> list[str]:
    """The diagnosis with ``effect`` alone: structure, base m_cap, each trial and rejection."""
    from gateway.diagnose import diagnose
    from gateway.diagnose.effects import EFFECTS

    g, w, k = label.split("/")
    if g in HELD_OUT:
        raise SystemExit(f"{g} is held out: not a dev generator")
    with tempfile.TemporaryDirectory() as tmp:
        data, gh, model, series = case_series(Case("diagnose", g, w, k), Path(tmp))
    d = diagnose(series, gh, model, library=(EFFECTS[effect],))
    truth = float((data.start - series.time[0]) / np.timedelta64(1, "s")) if data.start else None
    kept = [s["structure"] for s in d.structure if s["kept"] and s["structure"] != "base"]
    m_cap = float(d.base_theta[d.base_model.index("m_cap")])
    out = [f"{label} ({data.size}): base + {', '.join(kept) or 'nothing'}, m_cap {m_cap:.2f}; "
           f"held-out MAE {d.before['free_run']['mae']:.3f} K; findings "
           f"{[f.effect.name for f in d.findings] or 'none'}"]
    for t in d.trials:
        starts = "/".join(f"{(s - truth) / 3600:+.1f}" for s in t["starts"]) if truth else "-"
        out.append(f"  tried: cut {t['cut']:+.3f} (vs reference {t['cut_reference']:+.3f}), "
                   f"p {t['p']:.3f}, halves {t['halves'][0]:+.3f}/{t['halves'][1]:+.3f}, "
                   f"starts − truth {starts} h, passed {t['ok']}")
    if not d.trials:
        out.append("  not tried (ΔBIC of its τ scan ≥ 0)")
    out += [f"  rejected: {r['reason']}" for r in d.rejected]
    return out


def fitted(label: str, effect: str) -> str:
    """The effect's parameters fitted on all data after the calibrated base."""
    from gateway.diagnose import effect_fit
    from gateway.diagnose.effects import EFFECTS, compose
    from tests.generality.tau_profile import _setup

    e = EFFECTS[effect]
    ctx, gh, m0, th0, n = _setup(label)
    m = compose(m0, [e], gh, ctx.duration)
    fit = effect_fit.fit_effect(ctx, m, m0, th0, e, [(0, n)], latest=False)
    th, dbic = fit.theta, fit.delta_bic
    own = [nm for nm in m.names if nm not in m0.names]
    return f"  fit on all data: {', '.join(f'{nm} {th[m.index(nm)]:.4g}' for nm in own)}, ΔBIC {dbic:.0f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", default=DEFAULT, help="generator/window/kind (dev only)")
    ap.add_argument("--effect", required=True, help="library effect name (effects.EFFECTS)")
    ap.add_argument("--fit", action="store_true", help="also its fit on all data")
    a = ap.parse_args(argv)
    for label in a.cases:
        print("\n".join(judged(label, a.effect)), flush=True)
        if a.fit:
            print(fitted(label, a.effect), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

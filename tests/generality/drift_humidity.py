"""Step 1 of the drift-humidity rule (stated in docs/effects.md "The drift's start on the
humidity"): the start the search reports for ``sensor_drift`` on the six dev drift cases
(``effect_fit.fit_effect`` on all the data after the calibrated base, as tau_profile.py reports
it), with the night vapour balance off and on (``humidity.DRIFT_EVIDENCE``), and the evidence's
ΔBIC at the truth and at each start. Never the held-out generator.

    python tests/generality/drift_humidity.py [refsim/autumn/drift ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.generators import CHANGE_DAY  # noqa: E402
from tests.generality.tau_profile import DAY, _setup  # noqa: E402

CASES = [f"{g}/{w}/drift" for g in ("refsim", "twonode") for w in ("autumn", "winter", "summer")]


def starts(label: str) -> str:
    """One line: start − truth [h] and rate, evidence off | on, and the evidence at each."""
    from gateway.diagnose import effect_fit, humidity
    from gateway.diagnose.effects import EFFECTS, compose

    ctx, gh, m0, th0, n = _setup(label)
    e = EFFECTS["sensor_drift"]
    m = compose(m0, [e], gh, ctx.duration)
    jt, ja = m.index(e.tau_name), m.index(e.amp_name)
    truth, seg = CHANGE_DAY * DAY, [(0, n)]
    out = []
    for on in (False, True):
        humidity.DRIFT_EVIDENCE = on
        th = effect_fit.fit_effect(ctx, m, m0, th0, e, seg, latest=False).theta
        ev = humidity.drift_profile(ctx.x, seg, np.array([th[jt]]), np.array([th[ja]]))[0]
        out.append(f"{(th[jt] - truth) / 3600:+7.1f} h {th[ja]:+.3f} K/d (ev {ev:+6.1f})")
    humidity.DRIFT_EVIDENCE = False
    ev_truth = humidity.drift_profile(ctx.x, seg, np.array([truth]), np.array([0.5]))[0]
    nh = humidity.night_hours(ctx.x, seg)
    nights = humidity._effective(nh["t"]) if nh is not None else 0
    return (f"{label:22s} off {out[0]} | on {out[1]} | ev at truth, 0.5 K/d {ev_truth:+6.1f} "
            f"({nights:.0f} nights)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", default=CASES, help="generator/window/drift (dev only)")
    a = ap.parse_args(argv)
    print("start − truth, rate: evidence off | on")
    for label in a.cases:
        print(starts(label), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

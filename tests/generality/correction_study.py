"""Study: the forecast error correction's features and settings, on the tuning windows only.

Scores the replays kept by ``tests/generality/forecasts.py --keep DIR`` again, once per
variant of gateway/estimate/correction.py: the final setting, each feature left out (a feature
column held at 0 is the same fit without it: the ridge gives it weight 0 and leaves the others
alone), the bias alone, other memories and ridges. Reads the refsim and twonode replays only,
never the held-out generator's. Prints, per variant, the mean (min-max) MAE ratio corrected /
combined over the 18 window-horizons with the measured weather / the outlook, and on how many
of the six windows ``corrected`` meets the issue-10 goals (``combined``'s in brackets).

    nice -n 5 .venv/bin/python tests/generality/correction_study.py out/fc
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.estimate import correction  # noqa: E402
from gateway.estimate import replay as rp  # noqa: E402
from tests.generality.outlook_variants import (  # noqa: E402
    ahead_by_steps,
    forecasts_by_steps,
    tuning_replays,
)

MARKED = ("combined", "corrected")


def _corrected(res, mask: np.ndarray, memory_s: float, ridge: float) -> None:
    """Replace ``corrected{,_outlook}`` by the variant's."""
    base = correction.features
    correction.features = lambda *a: base(*a) * mask  # type: ignore[assignment]
    try:
        for suffix in ("", "_outlook"):
            comb, arx, starts = forecasts_by_steps(res, suffix)
            got = correction.correct_series(comb, res.measured, res.x, res.time, res.dt, arx,
                                            memory_s, ridge,
                                            ahead=ahead_by_steps(res, suffix, starts))
            for minutes, f in res.horizons.items():
                f[f"corrected{suffix}"] = got[int(round(minutes * 60.0 / res.dt))][starts[minutes]]
    finally:
        correction.features = base  # type: ignore[assignment]


def variant(replays: list, mask: np.ndarray, memory_s: float, ridge: float) -> str:
    ratios: dict[str, list[float]] = {"": [], "_outlook": []}
    measured, outlook = dict.fromkeys(MARKED, 0), dict.fromkeys(MARKED, 0)
    for res in replays:
        _corrected(res, mask, memory_s, ridge)
        hs = rp.report(res, warmup=int(round(86400.0 / res.dt)))["horizons"]
        for name in MARKED:
            measured[name] += all(h[name]["mae"] <= 0.7 * h["persistence"]["mae"]
                                  and h[name]["mae"] < h["arx"]["mae"] for h in hs.values())
            outlook[name] += all(h[f"{name}_outlook"]["mae"] <= 0.8 * h["persistence"]["mae"]
                                 for m, h in hs.items() if int(m) >= 30)
        for suffix, r in ratios.items():
            r += [h[f"corrected{suffix}"]["mae"] / h[f"combined{suffix}"]["mae"] for h in hs.values()]
    cells = [f"{np.mean(r):.3f} ({min(r):.3f}-{max(r):.3f})" for r in ratios.values()]
    return (f"{cells[0]} | {cells[1]} | {measured['corrected']} ({measured['combined']}) | "
            f"{outlook['corrected']} ({outlook['combined']})")


def variants() -> list[tuple[str, np.ndarray, float, float]]:
    names, mem, ridge = correction.FEATURES, correction.MEMORY_S, correction.RIDGE
    full = np.ones(len(names))
    out = [(f"final (memory {mem / 86400:.0f} d, ridge {ridge:.0f})", full, mem, ridge)]

    def drop(gone: tuple[str, ...]) -> np.ndarray:
        return np.array([0.0 if n in gone else 1.0 for n in names])

    harmonic = ("sin hour", "cos hour")
    for n in names[1:]:
        if n not in harmonic:
            out.append((f"without {n}", drop((n,)), mem, ridge))
    out.append(("without the daily harmonic", drop(harmonic), mem, ridge))
    out.append(("bias alone", drop(names[1:]), mem, ridge))
    out += [(f"memory {d} d", full, d * 86400.0, ridge) for d in (1, 2, 7, 14)]
    out += [(f"ridge {r}", full, mem, float(r)) for r in (5, 20, 200)]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kept", help="the directory of tests/generality/forecasts.py --keep")
    a = ap.parse_args(argv)
    replays = [res for _, res in tuning_replays(a.kept)]
    print(f"{len(replays)} tuning windows\n")
    print("| variant | corrected / combined, measured | same, outlook | measured goal (combined) "
          "| outlook goal (combined) |\n| --- | --- | --- | --- | --- |")
    for label, mask, mem, ridge in variants():
        print(f"| {label} | {variant(replays, mask, mem, ridge)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

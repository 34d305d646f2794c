"""Bench: a full diagnosis of 14 days of one-minute data on one core (issue 4: ≤ 60 s).

Data: the reference simulator (both plants, real Bleiswijk weather from 2009-11-01, seed 1) with
one undeclared effect each: a cover transmission change (× 0.6) on day 10, and a 25 W m-2 heater
from the evening of day 8. Writes bench/results/diagnose.json with the time, the findings and
the held-out free-run MAE before/after beside persistence.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, machine, one_core  # noqa: E402


def run() -> dict:
    one_core()
    from gateway.diagnose import diagnose
    from gateway.greenhouse import load_greenhouse
    from gateway.model import build_model
    from gateway.series import load_series
    from training.simulate import simulate

    out = {"machine": machine(), "cases": []}
    cases = [("cover_transmission@2009-11-11T10:00:factor=0.6", "solar_gain_change"),
             ("heater@2009-11-08T18:00:power=25", "heat_source")]
    for plant, preset in (("almeria", "almeria-palmerillas"), ("prototype", "biskra-prototype")):
        for spec, expected in cases:
            r = simulate(plant=plant, weather="bleiswijk", start="2009-11-01", days=14, seed=1,
                         effects=[spec])
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "data.csv"
                r.write(path)
                gh = load_greenhouse(preset)
                model = build_model(plant, gh)
                series = load_series(path, step=60.0, required=model.requires)
                t0 = time.perf_counter()
                d = diagnose(series, gh, model)
                seconds = time.perf_counter() - t0
            before, after = d.before["free_run"]["mae"], d.after["free_run"]["mae"]
            out["cases"].append({
                "plant": plant, "effect": spec, "samples": len(series), "seconds": seconds,
                "limit_s": 60.0,
                "findings": [(f.effect.name, f.start, f.amplitude) for f in d.findings],
                "first_finding_expected": expected,
                "first_finding_ok": bool(d.findings) and d.findings[0].effect.name == expected,
                "free_run_mae_before": before, "free_run_mae_after": after,
                "free_run_mae_cut": 1.0 - after / before,
                "persistence_free_run_mae": d.persistence["free_run"]["mae"],
                "base_structure": [s["structure"] for s in d.structure if s["kept"]],
            })
    return out


if __name__ == "__main__":
    result = run()
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "diagnose.json").write_text(json.dumps(result, indent=2), encoding="utf-8")
    print(json.dumps(result["cases"], indent=2))

"""Bench: a full diagnosis of 14 days of one-minute data on one core (issue 4: ≤ 60 s).

Data: the reference simulator (almeria plant, Bleiswijk weather from 2009-11-01, seed 1) with a
cover transmission change (× 0.6) on day 10, not declared. Writes bench/results/diagnose.json.
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
    for plant, preset in (("almeria", "almeria-palmerillas"), ("prototype", "biskra-prototype")):
        r = simulate(plant=plant, weather="bleiswijk", start="2009-11-01", days=14, seed=1,
                     effects=["cover_transmission@2009-11-11T10:00:factor=0.6"])
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "data.csv"
            r.write(path)
            gh = load_greenhouse(preset)
            model = build_model(plant, gh)
            series = load_series(path, step=60.0, required=model.requires)
            t0 = time.perf_counter()
            d = diagnose(series, gh, model)
            seconds = time.perf_counter() - t0
        out["cases"].append({
            "plant": plant, "samples": len(series), "seconds": seconds, "limit_s": 60.0,
            "findings": [(f.effect.name, f.start, f.amplitude) for f in d.findings],
            "free_run_mae_before": d.before["free_run"]["mae"],
            "free_run_mae_after": d.after["free_run"]["mae"],
            "persistence_free_run_mae": d.persistence["free_run"]["mae"],
        })
    return out


if __name__ == "__main__":
    result = run()
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "diagnose.json").write_text(json.dumps(result, indent=2), encoding="utf-8")
    print(json.dumps(result["cases"], indent=2))

"""Bench: a full diagnosis of 14 days of 5-minute kit data on one core (issue 10: ≤ 15 s).

Data (tests/generality/diagnosis_cases.py): the kit box from both generators we may use (the
reference simulator and tests/twonode.py) on the autumn window (real Bleiswijk weather from
2009-10-20), kit sensors only (t_in, rh_in, t_out, rh_out, i_glob, wind), effect-free and with
a 25 W m-2 heater from day 6.4; the prototype model. Writes bench/results/diagnose.json with
the wall-clock and CPU time of each diagnosis, the findings and the held-out free-run MAE
before/after beside persistence. CPU time is what one core spends: on a shared machine the
wall clock also counts the other processes' turns.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from _common import RESULTS, machine, one_core  # noqa: E402

LIMIT_S = 15.0


def run() -> dict:
    one_core()
    from gateway.diagnose import diagnose
    from gateway.model import build_model
    from tests.generality.diagnosis_cases import make_case
    from tests.generality.windows import load_window

    window = load_window("autumn")
    out = {"machine": machine(), "limit_s": LIMIT_S, "cases": []}
    for generator in ("refsim", "twonode"):
        for kind in ("none", "heat"):
            case = make_case(generator, "box", window, kind)
            model = build_model("prototype", case.gh)
            t0, c0 = time.perf_counter(), time.process_time()
            d = diagnose(case.series, case.gh, model)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            before, after = d.before["free_run"]["mae"], d.after["free_run"]["mae"]
            out["cases"].append({
                "generator": generator, "window": window.name, "kind": kind,
                "rows": len(case.series), "step_s": case.series.step,
                "seconds": wall, "cpu_seconds": cpu, "within_limit": cpu <= LIMIT_S,
                "findings": [(f.effect.name, f.start, f.amplitude) for f in d.findings],
                "free_run_mae_before": before, "free_run_mae_after": after,
                "persistence_free_run_mae": d.persistence["free_run"]["mae"],
                "base_structure": [s["structure"] for s in d.structure if s["kept"]],
            })
    return out


def main(argv: list[str] | None = None) -> int:
    """Parse the command line (``--help`` only), run the bench, write and print its JSON."""
    parser = argparse.ArgumentParser(
        prog="tests/bench/diagnose.py", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"Takes no other arguments; writes {RESULTS / 'diagnose.json'} and prints the "
               "cases. Also run by `make bench` (tests/bench/run.py).")
    parser.parse_args(argv)
    result = run()
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "diagnose.json").write_text(json.dumps(result, indent=2), encoding="utf-8")
    print(json.dumps(result["cases"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Bench: a full diagnosis of 14 days of 5-minute kit data on one core (issue 10: ≤ 15 s).

Data (tests/generality/diagnosis_cases.py): the kit box from both generators we may use (the
reference simulator and tests/twonode.py) on the autumn window (real Bleiswijk weather from
2009-10-20), kit sensors only (t_in, rh_in, t_out, rh_out, i_glob, wind), effect-free and with
a 25 W m-2 heater from day 6.4; the prototype model. Writes bench/results/diagnose.json with
the wall-clock and CPU time of each diagnosis, the findings and the held-out free-run MAE
before/after beside persistence. CPU time is what one core spends: on a shared machine the
wall clock also counts the other processes' turns.

``--against REF`` (a git commit or branch) times only the slowest case, twonode with the heater,
this tree against REF's code exported by ``git archive``, in interleaved rounds (one process per
tree per round, each the best of ``--repeat`` CPU times of the diagnosis; the case is simulated
by each tree's own code): both trees' CPU seconds per round, the median of the rounds' ratios
this tree / REF, and whether the findings and the free-run MAE before/after are the same to
the bit in every round (bench/results/diagnose_against.json).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The tree under test first (this checkout, or the one --against exported): tests/bench/gateway.py
# must not shadow the gateway package.
sys.path.insert(0, os.environ.get("SERRA_TREE", str(Path(__file__).resolve().parents[2])))
from _common import RESULTS, against, machine, one_core, write_result  # noqa: E402

LIMIT_S = 15.0
AGAINST_CASE = ("twonode", "heat")  # the slowest diagnosis of run()
AGAINST_ROUNDS, AGAINST_REPEAT = 4, 3


def _diagnose_case(generator: str, kind: str, window, repeat: int = 1) -> dict:
    """Simulate one case and diagnose it ``repeat`` times: the fastest run's wall-clock and CPU
    seconds [s] (each run gives the same diagnosis), its findings and free-run MAE [K]."""
    from gateway.diagnose import diagnose
    from gateway.model import build_model
    from tests.generality.diagnosis_cases import make_case

    case = make_case(generator, "box", window, kind)
    model = build_model("prototype", case.gh)
    wall = cpu = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        d = diagnose(case.series, case.gh, model)
        wall, cpu = min(wall, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    return {
        "generator": generator, "window": window.name, "kind": kind,
        "rows": len(case.series), "step_s": case.series.step,
        "seconds": wall, "cpu_seconds": cpu, "within_limit": cpu <= LIMIT_S,
        "findings": [(f.effect.name, f.start, f.amplitude) for f in d.findings],
        "free_run_mae_before": d.before["free_run"]["mae"],
        "free_run_mae_after": d.after["free_run"]["mae"],
        "persistence_free_run_mae": d.persistence["free_run"]["mae"],
        "base_structure": [s["structure"] for s in d.structure if s["kept"]],
    }


def run() -> dict:
    one_core()
    from tests.generality.windows import load_window

    window = load_window("autumn")
    cases = [_diagnose_case(generator, kind, window)
             for generator in ("refsim", "twonode") for kind in ("none", "heat")]
    return {"machine": machine(), "limit_s": LIMIT_S, "cases": cases}


def against_round(repeat: int) -> dict:
    """One process's figure for ``--against``: AGAINST_CASE's diagnosis, best of ``repeat``."""
    one_core()
    from tests.generality.windows import load_window

    return _diagnose_case(*AGAINST_CASE, load_window("autumn"), repeat)


def run_against(ref: str, rounds: int, repeat: int) -> dict:
    """AGAINST_CASE, this tree against ``ref``'s code, interleaved (module docstring)."""
    base, this = against(__file__, ref, rounds, ["--repeat", str(repeat)])
    ratios = [t["cpu_seconds"] / b["cpu_seconds"] for b, t in zip(base, this, strict=True)]
    same = ("findings", "free_run_mae_before", "free_run_mae_after")
    return {"ref": ref, "case": "-".join(AGAINST_CASE), "repeat": repeat,
            "rounds": {"this": this, ref: base},
            "summary": {"cpu_s_this": [round(t["cpu_seconds"], 3) for t in this],
                        f"cpu_s_at_{ref}": [round(b["cpu_seconds"], 3) for b in base],
                        "this_over_ref_per_round": [round(r, 3) for r in ratios],
                        f"this_over_{ref}_median_of_rounds": statistics.median(ratios),
                        "same_findings_and_mae": all(b[k] == t[k] for b, t in
                                                     zip(base, this, strict=True) for k in same)}}


def main(argv: list[str] | None = None) -> int:
    """Parse the command line, run the bench (or its ``--against`` mode), write and print JSON."""
    parser = argparse.ArgumentParser(
        prog="tests/bench/diagnose.py", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"Without options: the four cases, written to {RESULTS / 'diagnose.json'}\n"
               "and printed; also run by `make bench` (tests/bench/run.py).")
    parser.add_argument("--against", metavar="REF",
                        help="only the twonode heater case, this tree against this git commit's "
                             "or branch's code")
    parser.add_argument("--rounds", type=int, default=AGAINST_ROUNDS, metavar="N",
                        help=f"with --against: interleaved rounds (default {AGAINST_ROUNDS})")
    parser.add_argument("--repeat", type=int, default=AGAINST_REPEAT, metavar="N",
                        help="with --against: diagnoses per process, the fastest counts "
                             f"(default {AGAINST_REPEAT})")
    parser.add_argument("--round", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.repeat < 1:
        parser.error("--rounds and --repeat take a whole number of at least 1")
    if args.round:  # one round in this process, JSON on the last line (used by --against)
        print(json.dumps(against_round(args.repeat)))
    elif args.against:
        result = run_against(args.against, args.rounds, args.repeat)
        print(write_result("diagnose_against", result))
        print(json.dumps(result["summary"], indent=2))
    else:
        result = run()
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / "diagnose.json").write_text(json.dumps(result, indent=2), encoding="utf-8")
        print(json.dumps(result["cases"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

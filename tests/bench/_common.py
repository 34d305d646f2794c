"""Shared bench plumbing: one core, machine facts, JSON results in bench/results/."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "bench" / "results"


def one_core() -> None:
    """Pin this process to one CPU and keep BLAS single-threaded (call before numpy work)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if hasattr(os, "sched_setaffinity"):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})


def machine() -> dict[str, Any]:
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpu": platform.processor() or platform.machine(),
        "cores_used": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def no_arguments(doc: str | None, name: str) -> None:
    """``--help`` for a bench that takes no arguments (it runs the bench otherwise), and a clear
    error on any other argument."""
    import argparse

    argparse.ArgumentParser(description=(doc or "").split("\n\n")[0],
                            epilog=f"writes bench/results/{name}.json").parse_args()


def write_result(name: str, result: dict[str, Any]) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps({"bench": name, "machine": machine(), **result}, indent=2) + "\n")
    return path


def against(script: str, ref: str, rounds: int,
            extra: Sequence[str] = ()) -> tuple[list, list]:
    """Interleaved rounds of ``script --round *extra`` (its last stdout line is JSON): one process
    on git ``ref``'s tree (``git archive`` into a temporary folder), one on this tree, ``rounds``
    times; (ref's results, this tree's)."""
    with tempfile.TemporaryDirectory(prefix="serra-bench-base-") as base:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", base], input=archive, check=True)
        trees: dict[str, list] = {"base": [], "this": []}
        for _ in range(rounds):
            for label, path in (("base", base), ("this", str(ROOT))):
                env = {**os.environ, "PYTHONPATH": path, "SERRA_TREE": path}
                out = subprocess.run([sys.executable, script, "--round", *extra], env=env, cwd=path,
                                     check=True, capture_output=True, text=True).stdout
                trees[label].append(json.loads(out.splitlines()[-1]))
    return trees["base"], trees["this"]

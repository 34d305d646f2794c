"""``make bench``: every tests/bench/<name>.py in its own process, JSON in bench/results/.

Each module exposes ``run() -> dict`` and writes ``bench/results/<name>.json`` when run alone;
running them in separate processes keeps peak-memory figures and failures apart.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import RESULTS  # noqa: E402


def main(argv: list[str]) -> int:
    import argparse

    found = [n for n in sorted(p.stem for p in HERE.glob("*.py") if not p.stem.startswith("_"))
             if n != "run"]
    parser = argparse.ArgumentParser(
        prog="python tests/bench/run.py", description=__doc__.split("\n\n")[0].replace("``", ""))
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"the benches to run (default: all of {', '.join(found)})")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in found]
    if unknown:
        parser.error(f"no bench named {', '.join(unknown)} (benches: {', '.join(found)})")
    names = args.names or found
    failed = []
    for name in names:
        print(f"== bench {name}", flush=True)
        t0 = time.perf_counter()
        code = subprocess.call([sys.executable, str(HERE / f"{name}.py")])
        print(f"   {name}: exit {code} in {time.perf_counter() - t0:.0f} s", flush=True)
        if code:
            failed.append(name)
    for name in names:
        path = RESULTS / f"{name}.json"
        if path.exists():
            print(f"-- {path.relative_to(HERE.parents[1])}")
            summary = json.loads(path.read_text()).get("summary")
            if summary:
                print(json.dumps(summary, indent=2))
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

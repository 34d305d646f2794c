"""``make run``'s process group (training/appliance/procs.py): the last sweep leaves nothing."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
from pathlib import Path

from training.appliance.procs import Group

SLEEPER = [sys.executable, "-c", "import time; time.sleep(600)"]


def test_the_sweep_reaps_a_child_of_the_group_that_no_name_holds(tmp_path: Path) -> None:
    """A Ctrl-C inside ``Popen`` (after the fork, while it waits for the exec) leaves a child in
    the group that ``Group`` never adopted. The sweep terminated it but never reaped it: it
    stayed in the group as a zombie, so the sweep waited its 15 s, reported a process that did
    not stop, and the run left a zombie behind (make run's Ctrl-C test failed once in 8)."""
    g = Group()
    named = g.start("named", SLEEPER, tmp_path / "named.log", tmp_path)
    stray = subprocess.Popen(SLEEPER, process_group=g.popen_group())  # as if interrupted
    try:
        assert g.stop("named", 30) == -signal.SIGTERM
        assert g.sweep(timeout=60)  # the stray one was there, and is terminated
        assert not g.alive()  # and reaped: no process, not even a zombie, is in the group
    finally:
        for p in (named, stray):
            with contextlib.suppress(ProcessLookupError):
                p.kill()

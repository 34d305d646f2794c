"""Child processes in one process group of their own, stopped in order and then swept.

The children (gateway, subscriber, simulated kit, and whatever they start, e.g. the gateway's
diagnosis) share a process group that is not the terminal's: a Ctrl-C at the terminal reaches
only the orchestrator, which stops them in order (kit, gateway, subscriber), and a last sweep
of the group leaves nothing behind.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Sequence
from pathlib import Path


class ChildError(RuntimeError):
    """A child that did not start (its log's tail is in the message)."""


class Group:
    def __init__(self) -> None:
        self.pgid: int | None = None
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self._lines: dict[str, queue.Queue[str]] = {}

    def popen_group(self) -> int:
        """The ``process_group`` for the next child: a new group for the first one."""
        return 0 if self.pgid is None else self.pgid

    def adopt(self, name: str, proc: subprocess.Popen) -> None:
        if self.pgid is None:
            self.pgid = proc.pid
        self.procs[name] = proc

    def start(self, name: str, argv: Sequence[str], log: Path, cwd: Path) -> subprocess.Popen:
        """Start ``argv`` in the group, stderr to ``log``, stdout read line by line."""
        with log.open("a") as err:
            proc = subprocess.Popen(list(argv), cwd=cwd, stdout=subprocess.PIPE, stderr=err,
                                    stdin=subprocess.DEVNULL, text=True,
                                    process_group=self.popen_group())
        self.adopt(name, proc)
        self.logs[name] = log
        lines: queue.Queue[str] = queue.Queue()
        self._lines[name] = lines
        threading.Thread(target=_pump, args=(proc, lines), daemon=True, name=f"out-{name}").start()
        return proc

    def wait_line(self, name: str, prefix: str, timeout: float) -> str:
        """The child's first stdout line starting with ``prefix`` (ChildError if it exits or
        ``timeout`` [s] passes first)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                line = self._lines[name].get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                raise ChildError(f"{name} not ready after {timeout:g} s: {self.tail(name)}") from None
            if not line:
                raise ChildError(f"{name} exited at start: {self.tail(name)}")
            if line.startswith(prefix):
                return line.strip()

    def tail(self, name: str, n: int = 8) -> str:
        log = self.logs.get(name)
        if log is None or not log.exists():
            return "(no log)"
        return " | ".join(log.read_text(errors="replace").splitlines()[-n:]) or "(empty log)"

    def dead(self) -> list[str]:
        """Children that have exited (by name)."""
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def stop(self, name: str, timeout: float) -> int | None:
        """SIGTERM, then SIGKILL after ``timeout`` [s]; returns the exit status."""
        proc = self.procs.get(name)
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return proc.returncode

    def alive(self) -> bool:
        """Whether any process of the group is still there."""
        if self.pgid is None:
            return False
        try:
            os.killpg(self.pgid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True

    def kill(self) -> None:
        """SIGKILL to every process of the group, at once (no waiting: a signal handler's)."""
        if self.pgid is not None:
            try:
                os.killpg(self.pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def sweep(self, timeout: float = 10.0) -> bool:
        """Terminate whatever is left in the group (then kill it); True when something was."""
        if not self.alive():
            return False
        assert self.pgid is not None
        for sig, wait in ((signal.SIGTERM, timeout), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(self.pgid, sig)
            except ProcessLookupError:
                break
            deadline = time.monotonic() + wait
            while self.alive() and time.monotonic() < deadline:
                self._reap()
                time.sleep(0.05)
            if not self.alive():
                break
        return True


    def _reap(self) -> None:
        """Reap our children of the group that have exited, so they leave it: the named ones,
        then any other (a Ctrl-C inside ``Popen``, after the fork, leaves a child in the group
        that no name holds; unreaped, it would stay there as a zombie until we exit)."""
        for p in self.procs.values():
            p.poll()
        assert self.pgid is not None
        while True:
            try:
                pid, _ = os.waitpid(-self.pgid, os.WNOHANG)
            except ChildProcessError:  # none of our children is left in the group
                return
            if pid == 0:
                return


def _pump(proc: subprocess.Popen, lines: queue.Queue[str]) -> None:
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.put(line)
    lines.put("")

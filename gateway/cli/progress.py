"""How the long commands (calibrate, replay, diagnose, vsensor; training.vsensor train) show their
progress on stderr, the one place for all of them.

On a terminal: a rich bar (redrawn in place, gone when done) or indented stage lines. Piped to a
file (cron, CI logs): plain ``progress: ...`` lines, no ANSI and no carriage return, at each
tenth of the work, at least every :data:`PACE_S` seconds of wall clock and ``done`` at the end,
so that a log shows a run of an hour is alive without filling up. ``quiet`` (``-q``): nothing
at all. stdout keeps the results only.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

PACE_S = 30.0
"""Longest wall-clock silence [s] of the plain lines while work is done."""


class PlainProgress:
    """The piped form of a progress bar: a callback as the rich one's, writing a line at each
    tenth of ``total`` and whenever ``pace_s`` seconds of ``clock`` have passed since the last.
    ``clock`` and ``pace_s`` are there so tests can count lines without timing anything."""

    def __init__(self, label: str, total: int, stream: TextIO,
                 clock: Callable[[], float] = time.monotonic, pace_s: float = PACE_S) -> None:
        self.label, self.total, self.stream = label, max(int(total), 0), stream
        self.clock, self.pace_s = clock, pace_s
        self.done = 0
        self.began = self.last = clock()
        self.tenths = 0  # tenths of the work already said
        self.description: str | None = None

    def __call__(self, advance: int = 1, info: str = "", description: str | None = None) -> None:
        self.done += advance
        self.description = description or self.description
        now = self.clock()
        tenths = min(10, self.done * 10 // self.total) if self.total else 0
        if tenths > self.tenths or now - self.last >= self.pace_s:
            self.tenths, self.last = max(tenths, self.tenths), now
            self.stream.write(self.line(now, info) + "\n")
            self.stream.flush()

    def finish(self) -> None:
        """The closing line (the callers' counts may stop short of ``total``: replay says every
        100 rows), so a log shows the work ended and how long it took."""
        self.stream.write(f"progress: {self.label} done, {self.clock() - self.began:.0f} s\n")
        self.stream.flush()

    def line(self, now: float, info: str = "") -> str:
        done = min(self.done, self.total) if self.total else self.done
        share = f"{100 * done // self.total} % ({done}/{self.total})" if self.total else str(done)
        words = [w for w in (self.description, info) if w]
        return (f"progress: {self.label} {share}, {now - self.began:.0f} s"
                + (f" ({', '.join(words)})" if words else ""))


@contextmanager
def progress_bar(label: str, total: int, quiet: bool = False,
                 stream: TextIO | None = None) -> Iterator[Any]:
    """A callback ``update(advance=1, info="", description=None)`` showing the work done of
    ``total``: a rich bar when ``stream`` (default stderr) is a terminal, plain lines
    otherwise (:class:`PlainProgress`), a no-op when ``quiet``."""
    stream = sys.stderr if stream is None else stream
    if quiet:
        yield lambda *a, **k: None
        return
    if not stream.isatty():
        plain = PlainProgress(label, total, stream)
        yield plain
        plain.finish()  # not after an error: the error line says how it ended
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TextColumn("{task.fields[info]}"),
        TimeRemainingColumn(),
        console=Console(file=stream),
        transient=True,
    ) as bar:
        task = bar.add_task(label, total=total, info="")

        def update(advance: int = 1, info: str = "", description: str | None = None) -> None:
            # description None: rich keeps the current one
            bar.update(task, advance=advance, info=info, description=description or None)

        yield update


def stage_printer(label: str, quiet: bool = False, stream: TextIO | None = None,
                  clock: Callable[[], float] = time.monotonic) -> Callable[[str], None]:
    """A callback ``say(message)`` for work told in stages rather than counted (diagnose's
    rounds): indented lines on a terminal, ``progress: LABEL: message, N s`` lines piped (each
    stage: they are minutes apart), nothing when ``quiet``."""
    out = sys.stderr if stream is None else stream
    tty, began = out.isatty(), clock()

    def say(message: str) -> None:
        if quiet:
            return
        out.write(f"  {message}\n" if tty else
                  f"progress: {label}: {message}, {clock() - began:.0f} s\n")
        out.flush()

    return say

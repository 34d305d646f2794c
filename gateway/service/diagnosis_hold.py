"""The daily diagnosis when the disk cannot be written: its round waits, the gateway goes on.

A round writes twice: the greenhouse's minutes as a CSV in the gateway's work folder (the
diagnose subprocess's input; on a Pi the same SD card as the store, systemd's PrivateTmp) and,
after the subprocess, its findings and run in the store. Before, either write failing (a full
card, a file-size limit) ended the scheduler's task and with it the gateway (exit 1: tried with
``prlimit`` RLIMIT_FSIZE on the running gateway). Now:

- the store's writes (and reads) go through the service's shared :class:`Outage`: the same one
  line, backoff and "back" line as ingest's and the worker's; the finished run is held in memory
  and kept once the store writes (the subprocess is not run again); a damaged store still stops
  the service (``StoreDamaged``);
- the CSV failing (an ``OSError`` of the work folder) postpones the greenhouse's run: one line,
  tried again after ``POSTPONE_FIRST_S`` doubling to every ``POSTPONE_MAX_S``, one line when it
  goes on.
"""

from __future__ import annotations

import asyncio
import logging
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.store.outage import Outage

log = logging.getLogger("serra.gateway")
POSTPONE_FIRST_S = 10.0  # [s] first try again of a run whose data could not be written
POSTPONE_MAX_S = 600.0  # [s] the ceiling: a run waits at most this long after the disk heals
PART = "diagnosis"  # the outage's name of this writer


async def settled(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a worker thread; when the caller is cancelled meanwhile, the thread is
    let finish before the cancellation goes on: the connection it uses is closed right after,
    and closing a SQLite connection under a running statement crashes the process."""
    fut = asyncio.ensure_future(asyncio.to_thread(fn, *args))
    try:
        return await asyncio.shield(fut)
    except asyncio.CancelledError:
        while not fut.done():
            try:
                await asyncio.wait([fut])
            except asyncio.CancelledError:
                continue
        raise


class RoundHold:
    """A round's writes, waited out: the store's through ``outage``, the data file's here."""

    def __init__(self, outage: Outage) -> None:
        self.outage = outage
        self._postponed: dict[str, float] = {}  # greenhouse -> its next wait [s]

    async def store(self, fn: Callable[..., Any], *args: Any, held: str = "") -> Any:
        """``fn(*args)`` on the store, off the loop, tried again after the outage's backoff while
        the store cannot be written; what is no store fault is raised as it was. ``held``: what
        waits, said once when it starts to (the store's own line says why)."""
        while True:
            try:
                out = await settled(fn, *args)
            except sqlite3.Error as e:
                delay = self._store_failed(e)
                if held:
                    log.warning("%s: held until the store can be written", held)
                    held = ""
                await asyncio.sleep(delay)
                continue
            self.outage.ok(PART)
            return out

    def _store_failed(self, e: sqlite3.Error) -> float:
        delay = self.outage.failed(PART, e)  # a damaged store raises: the service stops
        if delay is None:
            raise e
        return delay

    async def data(self, greenhouse: str, path: Path, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)``, which reads the store and writes the run's data to ``path``, tried
        again while either cannot be written (the run postponed, said once)."""
        while True:
            try:
                out = await settled(fn, *args)
            except sqlite3.Error as e:  # a read refused: a lock held elsewhere, a failing card
                await asyncio.sleep(self._store_failed(e))
                continue
            except OSError as e:  # the work folder's disk full, a file-size limit
                await asyncio.sleep(self._postpone(greenhouse, path, e))
                continue
            self.outage.ok(PART)
            if self._postponed.pop(greenhouse, None) is not None:
                log.warning("greenhouse %s: diagnosis goes on, its data written", greenhouse)
            return out

    def _postpone(self, greenhouse: str, path: Path, e: OSError) -> float:
        delay = self._postponed.get(greenhouse)
        if delay is None:
            delay = POSTPONE_FIRST_S
            log.warning("greenhouse %s: diagnosis postponed, its data cannot be written to %s "
                        "(%s); tried again after %g s, then less often (at most every %g min)",
                        greenhouse, path.parent, e.strerror or e, delay, POSTPONE_MAX_S / 60)
        self._postponed[greenhouse] = min(2 * delay, POSTPONE_MAX_S)
        return delay

"""A store that cannot be written (a full or failing SD card): which faults are waited out and
which end the service, said in one line each way.

Every part of a service that writes the store (the ingest writer, its maintenance, the live
gateway's worker and publisher) hands its failed write to one shared ``Outage``:

- a fault that may heal — SQLite's ``SQLITE_FULL``, ``SQLITE_IOERR*`` (a write past a full disk
  or a file-size limit, a failing card), ``SQLITE_READONLY*``, ``SQLITE_CANTOPEN``,
  ``SQLITE_BUSY``/``SQLITE_LOCKED`` (another program holds the lock) — is said once, naming the
  file and the cause, and the part retries after a backoff (``RETRY_FIRST_S`` doubling to
  ``RETRY_MAX_S``); a reminder every ``REMIND_S`` while it lasts, one "back" line once every part
  that failed has written again;
- a damaged file (``SQLITE_CORRUPT*``, ``SQLITE_NOTADB``) or one deleted or replaced while open
  (``StoreGone``) raises ``StoreDamaged``: writing on would not heal it, the service stops;
- anything else is not a store fault and is raised again as it was.

SQLite names no errno: a write refused with EFBIG (a file-size limit) or EIO is the same
``disk I/O error`` (``SQLITE_IOERR_WRITE``) and only ENOSPC is ``database or disk is full``, so
the cause is completed from the file system (free space, the file's existence, RLIMIT_FSIZE).
What was tried, and what each service then does: docs/gateway.md, "A full or failing store".
"""

from __future__ import annotations

import logging
import os
import resource
import shutil
import sqlite3
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.store.db import StoreError, StoreGone

log = logging.getLogger("serra.store")

RETRY_FIRST_S = 1.0  # [s] first retry after a failed write
RETRY_MAX_S = 10.0  # [s] the backoff's ceiling: a healed disk is used again within this
REMIND_S = 600.0  # [s] between "still failing" lines
LOW_FREE_BYTES = 1 << 20  # an I/O error with less free than this is taken for a full disk

_DAMAGED = ("SQLITE_CORRUPT", "SQLITE_NOTADB")
_RETRIED = ("SQLITE_FULL", "SQLITE_IOERR", "SQLITE_READONLY", "SQLITE_CANTOPEN", "SQLITE_BUSY",
            "SQLITE_LOCKED", "SQLITE_PROTOCOL")


EX_DAMAGED = os.EX_DATAERR
"""65, sysexits' EX_DATAERR: the exit of a service whose store file is damaged (at start or
while it runs). It does not mend by itself: each restart would read the same bytes and fail
the same way, every 5 s for ever, so the units list it in RestartPreventExitStatus= and stay
failed with this one line until a person recovers, restores or moves the file aside. A store
deleted or replaced while open stays exit 1: a restart opens it anew, which is the remedy."""


class StoreDamaged(StoreError):
    """The store's file is damaged or gone: the service stops with this one line."""


class StoreCorrupt(StoreDamaged):
    """The store's file is damaged (SQLite: SQLITE_CORRUPT*, SQLITE_NOTADB): exit EX_DAMAGED."""


def _errorname(e: sqlite3.Error) -> str:
    return getattr(e, "sqlite_errorname", "") or ""


def _free_bytes(path: Path) -> int | None:
    try:
        return shutil.disk_usage(path.parent).free
    except OSError:
        return None


def cause(e: BaseException, path: Path) -> str | None:
    """Why ``path`` cannot be written, in words, when ``e`` is a fault that may heal (a full
    disk, an I/O error, a lock held elsewhere); None for any other exception."""
    if isinstance(e, OSError) and not isinstance(e, StoreError):
        return (e.strerror or str(e)).lower()
    if not isinstance(e, sqlite3.Error):
        return None
    name = _errorname(e)
    if not name.startswith(_RETRIED):
        return None
    said = f"SQLite: {e}"
    free = _free_bytes(path)
    if (name == "SQLITE_FULL" or name.startswith("SQLITE_IOERR")) and (
            free is not None and free < LOW_FREE_BYTES):
        return f"disk full ({said}; {free} bytes free)"
    if name == "SQLITE_FULL":  # ENOSPC with room: a quota, a file system's size limit
        return f"no room ({said}; {free} bytes free on its disk: a quota or a size limit?)"
    if not path.parent.is_dir():
        return f"its folder {path.parent} is gone ({said})"
    if name.startswith("SQLITE_IOERR"):
        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if soft != resource.RLIM_INFINITY:
            return f"file size limit reached (RLIMIT_FSIZE {soft} bytes; {said})"
        return f"write failed (a failing SD card? {said})"
    if name.startswith("SQLITE_READONLY"):
        return f"read-only (the file, its folder or the file system; {said})"
    if name.startswith("SQLITE_CANTOPEN"):
        return f"cannot open its files in {path.parent} ({said})"
    return f"locked by another program ({said})"


def damaged(e: BaseException, path: Path) -> StoreDamaged | None:
    """The exception that ends the service when ``e`` says the file is damaged or gone."""
    if isinstance(e, StoreGone):
        return StoreDamaged(f"{e}: stopping, nothing more is acknowledged; a restart opens the "
                            "store anew at that path")
    if isinstance(e, sqlite3.Error) and _errorname(e).startswith(_DAMAGED):
        return StoreCorrupt(f"{path}: the store is damaged (SQLite: {e}): stopping, nothing more "
                            f"is acknowledged; check it (sqlite3 {path} 'PRAGMA "
                            "integrity_check'), then recover it ('.recover') or restore a copy, "
                            "or move it aside (a new store is made), and start the service again")
    return None


def exit_status(e: StoreDamaged) -> int:
    """The exit of a service stopped by ``e``: EX_DAMAGED for a damaged file, else 1."""
    return EX_DAMAGED if isinstance(e, StoreCorrupt) else 1


class Outage:
    """The store's write failures, shared by the parts of one service (thread-safe)."""

    def __init__(self, path: str | Path, consequence: str,
                 on_change: Callable[[], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """``consequence``: what the service's line says follows (e.g. "records not acked, the
        kits keep them"); ``on_change()``: called when the store starts failing or comes back
        (the systemd STATUS= line)."""
        self.path = Path(path)
        self.consequence, self.on_change, self.clock = consequence, on_change, clock
        self._lock = threading.Lock()
        self._delay: dict[str, float] = {}  # failing part -> its next backoff [s]
        self.cause: str | None = None  # while failing
        self.since = 0.0  # [wall unix s] the outage's first failure
        self._t0 = self._reminded = 0.0  # [clock s]
        self.failures = 0  # failed writes in this outage
        self.last: dict[str, Any] | None = None  # the latest outage that ended
        self._damaged = False

    @property
    def failing(self) -> bool:
        return self.cause is not None

    def failed(self, part: str, e: BaseException) -> float | None:
        """A write of ``part`` failed with ``e``: the seconds it waits before trying again; None
        when ``e`` is no store fault (the caller's to handle). Raises StoreDamaged (said in the
        log) for a damaged or deleted file."""
        bad = damaged(e, self.path)
        if bad is not None:
            if not self._damaged:  # said once, whichever part meets it next
                self._damaged = True
                log.error("%s", bad)
            raise bad from None
        why = cause(e, self.path)
        if why is None:
            return None
        log.debug("%s: a write of the %s failed: %s", self.path, part, e)
        say: str | None = None
        with self._lock:
            now = self.clock()
            delay = self._delay.get(part, RETRY_FIRST_S)
            self._delay[part] = min(2 * delay, RETRY_MAX_S)
            self.failures += 1
            if self.cause is None:
                self.cause, self.since, self._t0 = why, time.time(), now
                self._reminded = now
                say = (f"{self.path}: {why} — {self.consequence}; retrying with backoff "
                       f"({RETRY_FIRST_S:g} s doubling to every {RETRY_MAX_S:g} s)")
            elif now - self._reminded >= REMIND_S:
                self._reminded = now
                log.error("%s: still cannot be written, for %.0f min now (%d failed writes): %s",
                          self.path, (now - self._t0) / 60, self.failures, why)
        if say is not None:
            log.error("%s", say)
            self._changed()
        return delay

    def ok(self, part: str) -> None:
        """``part`` wrote again; the store is back once every part that failed has."""
        if part not in self._delay:  # the common case, without the lock
            return
        with self._lock:
            self._delay.pop(part, None)
            if self._delay or self.cause is None:
                return
            took = self.clock() - self._t0
            self.last = {"cause": self.cause, "since": self.since, "until": time.time(),
                         "failures": self.failures}
            log.warning("%s: back, writes succeed again after %.0f s (%d failed writes)",
                        self.path, took, self.failures)
            self.cause, self.failures = None, 0
        self._changed()

    def _changed(self) -> None:
        if self.on_change is not None:
            try:
                self.on_change()
            except Exception:  # a listener's fault must not hide the store's
                log.exception("store outage listener failed")

    def status(self) -> dict[str, Any]:
        """For the status row and the gateway's published status."""
        with self._lock:
            return {"failing": self.failing, "cause": self.cause,
                    "since": self.since if self.failing else None, "failures": self.failures,
                    "last": self.last}

    def status_line(self) -> str:
        """The systemd STATUS= part: empty while the store writes."""
        cause, since = self.cause, self.since
        if cause is None:
            return ""
        return (f"STORE FAILING since {time.strftime('%H:%M:%S', time.localtime(since))}: "
                f"{cause}")

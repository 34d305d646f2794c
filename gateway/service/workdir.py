"""The gateway's work folder: a private temporary folder for the files its diagnosis subprocess
reads (a greenhouse's exported minutes), removed when the gateway stops (SIGTERM, SIGINT, or a
part failing), and at a later start when the gateway that made it was killed (SIGKILL, an OOM
kill, a second Ctrl-C of ``make run``): nothing else ever would, outside systemd, whose
PrivateTmp=yes empties the unit's own /tmp at each stop.

A folder is removed at start only when it is clearly a dead gateway's: directly in the
temporary folder ($TMPDIR, else /tmp), named with this module's own prefix (``serra-gateway-``:
other tools of the project name theirs ``serra-…`` too, and those are never touched), a real
folder owned by this user, holding the lock file its gateway kept locked (flock) for as long as
it ran. The kernel drops that lock when the process ends, however it ends, and only then can
another take it: a lock taken means no process holds the folder. The lock file is locked before
it gets its name (a rename), so no other gateway can take it in between; a folder without one
(made by something else, or by a gateway killed in the microseconds before the rename) stays.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

log = logging.getLogger("serra.gateway")
PREFIX = "serra-gateway-"
LOCK = "gateway.lock"


@contextlib.contextmanager
def work_folder() -> Iterator[Path]:
    """A new work folder in the temporary folder, locked as this process's for as long as the
    block runs and removed at its end; the folders of killed gateways are removed first."""
    sweep_stale()
    path = Path(tempfile.mkdtemp(prefix=PREFIX))
    fd = -1
    try:
        fd = _lock(path)
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)  # still locked: no sweep takes it meanwhile
        if fd >= 0:
            os.close(fd)


def _lock(folder: Path) -> int:
    """Create the folder's lock file, locked, then give it its name; -1 where the file system
    has no flock (the folder then has no lock file: never taken for a dead gateway's)."""
    new = folder / f"{LOCK}.new"
    fd = os.open(new, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return -1
    os.rename(new, folder / LOCK)
    return fd


def sweep_stale(root: Path | None = None) -> list[Path]:
    """Remove the work folders of gateways that are gone from ``root`` (the temporary folder);
    returns them."""
    root = Path(root) if root is not None else Path(tempfile.gettempdir())
    try:
        entries = [e for e in os.scandir(root) if e.name.startswith(PREFIX)]
    except OSError:
        return []
    removed = []
    for e in entries:
        try:
            st = e.stat(follow_symlinks=False)
        except OSError:
            continue
        if stat.S_ISDIR(st.st_mode) and st.st_uid == os.geteuid() and _remove_if_dead(Path(e.path)):
            removed.append(Path(e.path))
    if removed:
        log.info("removed the work folder(s) of gateways that were killed: %s",
                 ", ".join(map(str, removed)))
    return removed


def _remove_if_dead(folder: Path) -> bool:
    """Remove ``folder`` when its lock file is ours and nobody holds its lock."""
    try:
        fd = os.open(folder / LOCK, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return False  # no lock file (or a link): not clearly a gateway's
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.geteuid():
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False  # held: its gateway runs
        shutil.rmtree(folder, ignore_errors=True)  # under the lock: no other sweep races it
        return not folder.exists()
    finally:
        os.close(fd)

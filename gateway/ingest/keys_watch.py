"""The keys file read again when it changes: adding or rotating a device needs no restart.

The ingest service looks at the file's identity (inode, modification time, size, mode) every
maintenance round. A file that changed and reads well replaces the keys in use
(``IngestCore.reload_keys``); one that is gone, unreadable or wrong is logged once, naming the
file, line and fault, and the keys in use stay: a typo while editing never locks the kits out.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from gateway.store.keys import KeyFileError, load_keys

log = logging.getLogger("serra.ingest")


class KeysWatch:
    def __init__(self, path: str | Path) -> None:
        """Take the file's identity now: call before the first ``load_keys`` so that a change
        made between the two is seen at the first look."""
        self.path = Path(path)
        self.stamp = self._stamp()

    def _stamp(self) -> tuple[int, int, int, int] | None:
        try:
            st = os.stat(self.path)
        except OSError:
            return None
        return (st.st_ino, st.st_mtime_ns, st.st_size, st.st_mode)

    def changed_keys(self) -> dict[int, bytes] | None:
        """The file's keys when it changed since the last look and reads well, else None."""
        stamp = self._stamp()
        if stamp == self.stamp:
            return None
        self.stamp = stamp
        if stamp is None:
            log.error("keys file %s is gone; the device keys read before stay in use", self.path)
            return None
        try:
            return load_keys(self.path)
        except (KeyFileError, OSError) as e:
            log.error("keys file changed but not taken: %s; the device keys read before stay in "
                      "use", e)
            return None

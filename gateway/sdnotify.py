"""systemd's readiness protocol (sd_notify(3)) without libsystemd: one datagram per message to
the unix socket ``$NOTIFY_SOCKET`` names. The units are ``Type=notify``, so ``systemctl start``
returns once the service says ``READY=1`` (or fails, on the spot, when it exits first)::

    notify = Notifier()                       # reads $NOTIFY_SOCKET, $WATCHDOG_USEC
    notify.ready("2 greenhouses, 3 kits")     # READY=1 + STATUS=... (systemctl status shows it)
    notify.status("zenoh linked")             # sent only when it changes
    notify.watchdog()                         # WATCHDOG=1, when the unit sets WatchdogSec=
    notify.stopping()                         # STOPPING=1: the shutdown has begun

Every method does nothing when ``$NOTIFY_SOCKET`` is unset (a terminal, the tests' processes).
A message that cannot be sent is logged once and dropped: the service goes on (under systemd a
lost READY=1 shows as a start time-out, which the log line then explains).
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger("serra.systemd")


def socket_address(name: str) -> str | bytes | None:
    """``$NOTIFY_SOCKET`` → an AF_UNIX address: a path, or an abstract name (``@name`` →
    ``\\0name``); None for what this module does not speak (vsock, a relative path)."""
    if name.startswith("/"):
        return name
    if name.startswith("@") and len(name) > 1:
        return b"\0" + name[1:].encode()
    return None


def _one_line(text: str) -> str:
    return text.replace("\n", " ")  # a newline would end the field


class Notifier:
    """One service's messages to systemd (see the module docstring)."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        name = env.get("NOTIFY_SOCKET", "")
        self.address = socket_address(name) if name else None
        if name and self.address is None:
            log.warning("NOTIFY_SOCKET=%s: not a unix socket path or @name; systemd is not "
                        "told when this service is ready", name)
        # sd_watchdog_enabled(3): WATCHDOG_PID, when set, names the process meant
        pid = env.get("WATCHDOG_PID", "")
        usec = env.get("WATCHDOG_USEC", "")
        mine = not pid or (pid.isdigit() and int(pid) == os.getpid())
        self.watchdog_s = int(usec) / 1e6 if usec.isdigit() and int(usec) > 0 and mine else 0.0
        self.readied = self.stopped = False
        self._status = ""
        self._failed = False

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def send(self, *fields: str) -> bool:
        """One datagram of ``KEY=value`` lines; True if it went out."""
        if self.address is None:
            return False
        msg = "\n".join(_one_line(f) for f in fields).encode()
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
                s.setblocking(False)  # a full queue drops a message, never stalls the service
                s.sendto(msg, self.address)
        except OSError as e:
            if not self._failed:
                self._failed = True
                log.warning("cannot tell systemd %s: %s", fields[0], e.strerror or e)
            return False
        return True

    def ready(self, status: str) -> None:
        """READY=1 with a first STATUS=."""
        if not self.stopped:
            self.readied, self._status = True, _one_line(status)
            self.send("READY=1", f"STATUS={status}")

    def status(self, text: str) -> None:
        """STATUS= when it differs from the last one sent."""
        text = _one_line(text)
        if self.readied and text != self._status and not self.stopped:
            self._status = text
            self.send(f"STATUS={text}")

    def watchdog(self) -> None:
        """WATCHDOG=1 when the unit asked for it (``WatchdogSec=``), else nothing."""
        if self.watchdog_s and self.readied and not self.stopped:
            self.send("WATCHDOG=1")

    def stopping(self, status: str = "stopping") -> None:
        """STOPPING=1, once, after READY=1 (before it systemd ignores it): systemd stops the
        watchdog and times the stop (TimeoutStopSec=)."""
        if self.readied and not self.stopped:
            self.stopped = True
            self.send("STOPPING=1", f"STATUS={status}")

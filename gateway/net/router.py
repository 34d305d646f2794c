"""A Zenoh router run by the Python library (``mode: router``; no zenohd is needed).

    with Router(settings) as router:      # opens the session
        print(router.locators)           # what it listens on (port 0 resolved)
    # closed: links dropped, the process can exit (a session left open hangs interpreter exit)

:func:`serve` is the long-running form behind ``python -m gateway router``: it prints one
``ready`` line, watches its upstream links and returns when `stop` is set (SIGTERM/SIGINT).
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from typing import Any

from gateway.net.routerconf import RouterSettings, router_entries
from gateway.net.zenohcfg import build
from gateway.sdnotify import Notifier

log = logging.getLogger("serra.router")
READY = "serra router ready:"  # the line tests and supervisors wait for


class Router:
    """One router session; a context manager that always closes it."""

    def __init__(self, settings: RouterSettings) -> None:
        self.settings = settings
        self.session: Any = None

    def open(self) -> Router:
        import zenoh

        conf = build(router_entries(self.settings))
        self.session = zenoh.open(conf)
        return self

    @property
    def zid(self) -> str:
        return str(self.session.zid())

    @property
    def locators(self) -> list[str]:
        """The endpoints the router listens on, with the ports it bound (read from its own
        admin space, ``@/<zid>/router``)."""
        for reply in self.session.get(f"@/{self.zid}/router", timeout=10.0):
            if reply.ok is not None:
                return list(json.loads(reply.ok.payload.to_string()).get("locators", []))
        return []

    def upstream(self) -> list[str]:
        """ZIDs of the routers this one has a link with."""
        return sorted(str(z) for z in self.session.info.routers_zid())

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None

    def __enter__(self) -> Router:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve(settings: RouterSettings, stop: threading.Event,
          on_ready: Callable[[Router], None] | None = None, watch_every: float = 5.0,
          notify: Notifier | None = None) -> int:
    """Run until `stop` is set; report the router's links as they change. Returns 0. Under
    systemd (``notify``, by default from $NOTIFY_SOCKET): READY=1 after the ready line (the
    session open, its listeners bound; upstream links are not waited for: they are retried for
    ever), STATUS= as the links change, STOPPING=1 when `stop` is set."""
    notify = notify or Notifier()
    for warning in settings.warnings():
        log.warning("%s", warning)
    with Router(settings) as router:
        listen = ",".join(router.locators)
        print(f"{READY} name={settings.name} zid={router.zid} listen={listen} "
              f"connect={','.join(settings.connect) or '-'} "
              f"access={'on' if settings.access and settings.access.enabled else 'off'}", flush=True)
        notify.ready(f"listening {listen or '-'}" + ("; upstream not linked yet"
                                                     if settings.connect else ""))
        if on_ready is not None:
            on_ready(router)
        seen: list[str] | None = None
        while not stop.wait(watch_every):
            now = router.upstream() if settings.connect else []
            if settings.connect and now != seen:
                if now:
                    log.info("router %s: linked to %d router(s): %s", settings.name, len(now),
                             ", ".join(z[:8] for z in now))
                else:
                    log.warning("router %s: no upstream router reachable (%s); retrying",
                                settings.name, ", ".join(settings.connect))
                notify.status(f"listening {listen or '-'}; " + (
                    f"linked to {len(now)} upstream router(s)" if now else "no upstream reachable"))
                seen = now
        notify.stopping()
        log.info("router %s: stopping", settings.name)
    return 0

"""A Zenoh session that opens when a router answers, retried in the background until then.

In client mode ``zenoh.open()`` fails when no router of the connect list answers (eclipse-zenoh
1.10: ``Unable to connect to any of [...]``), whatever ``connect/exit_on_failure`` says. A
gateway must start anyway (ingest and the estimators do not need the network; its outbox
holds the messages), so it opens through :class:`SessionOpener`::

    opener = SessionOpener(lambda: build(entries), on_open=attach, retry=Retry(500, 4000))
    opener.start()          # one attempt now; on failure a thread retries (500 ms, doubling to 4 s)
    ...
    opener.stop()           # stops retrying; returns the session if it opened (the caller closes it)

Once open, the session reconnects by itself for ever (``connect/retry``): the opener's job ends
at the first success. ``on_open(session)`` runs once, on the thread that opened it; if it
raises, the session is closed and the error is kept in :attr:`SessionOpener.error`.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gateway.net.zenohcfg import Retry

log = logging.getLogger("serra.zenoh")


@dataclass
class OpenState:
    """What the status screen shows while the session is not open yet."""

    open: bool = False
    attempts: int = 0
    last_error: str = ""  # one line, Zenoh's source location cut off
    since: float = 0.0  # wall time of the first attempt [unix s]
    opened_at: float | None = None


def short_error(exc: BaseException) -> str:
    """Zenoh's message without the Rust source location (`` at /root/.cargo/...``) and its
    ``Single(...)`` wrappers round endpoints."""
    return re.sub(r"Single\(([^()]*)\)", r"\1", str(exc).split(" at /")[0].strip())


class SessionOpener:
    """Open a Zenoh session, retrying in a thread until it opens or :meth:`stop` is called."""

    def __init__(self, make_config: Callable[[], Any], on_open: Callable[[Any], None],
                 retry: Retry | None = None, what: str = "zenoh") -> None:
        self.make_config, self.on_open, self.what = make_config, on_open, what
        self.retry = retry or Retry()
        self.state = OpenState()
        self.session: Any = None
        self.error: BaseException | None = None  # on_open failed (the session was closed)
        self.opened = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()  # open + on_open vs stop
        self._thread: threading.Thread | None = None

    def start(self, background: bool = True) -> bool:
        """One attempt now; on failure, retry in a background thread (unless not `background`).
        True if open now."""
        self.state.since = time.time()
        if self._attempt() or not background:
            return self.opened.is_set()
        log.warning("%s: cannot open the session (%s); retrying every %g-%g s in the background",
                    self.what, self.state.last_error, self.retry.initial_ms / 1000,
                    self.retry.max_ms / 1000)
        self._thread = threading.Thread(target=self._run, name="serra-zenoh-open", daemon=True)
        self._thread.start()
        return False

    def _attempt(self) -> bool:
        import zenoh

        with self._lock:
            if self._stop.is_set():
                return False
            self.state.attempts += 1
            try:
                session = zenoh.open(self.make_config())
            except zenoh.ZError as exc:
                text = short_error(exc)
                if text != self.state.last_error and self.state.attempts > 1:
                    log.warning("%s: still cannot open the session: %s", self.what, text)
                self.state.last_error = text
                return False
            try:
                self.on_open(session)
            except BaseException as exc:
                self.error = exc
                session.close()
                log.error("%s: the session opened but could not be used: %s", self.what, exc)
                self.opened.set()  # nothing more will happen: waiters wake up and see the error
                return True
            self.session = session
            self.state.open, self.state.opened_at = True, time.time()
        if self.state.attempts > 1:
            log.info("%s: session open after %d attempts (%.1f s)", self.what, self.state.attempts,
                     time.time() - self.state.since)
        self.opened.set()
        return True

    def _run(self) -> None:
        wait = self.retry.initial_ms / 1000
        while not self._stop.wait(wait):
            if self._attempt():
                return
            wait = min(wait * self.retry.factor, self.retry.max_ms / 1000)

    def stop(self, timeout: float = 30.0) -> Any:
        """Stop retrying (an attempt in progress finishes first); returns the open session or
        None. The caller undeclares what ``on_open`` declared and closes it."""
        with self._lock:
            self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        return self.session

"""The interactive status screen (Textual): three panels over one :class:`Snapshot`, refreshed
in a thread every few seconds. Usable over SSH on an 80×24 terminal.

Keys: ``1``/``g`` greenhouse, ``2``/``k`` kits, ``3``/``w`` gateway, ``tab`` next panel,
``←``/``→`` (or ``p``/``n``) previous/next greenhouse, ``↑``/``↓``/PgUp/PgDn scroll, ``r`` refresh
now, ``q`` (or Ctrl-C) quit. The snapshot comes from a source (the store, read-only, or Zenoh);
the app only draws it, at the width the terminal gives (80 columns or more shows every line whole
as ``--once`` does; a wider one shows what 78 columns would cut; a narrower one cuts at a word).
"""

from __future__ import annotations

import asyncio
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol

from rich.console import Console, ConsoleOptions
from rich.text import Text
from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.widgets import Footer, Static

from gateway.status import render
from gateway.status.snapshot import Snapshot


class Source(Protocol):
    label: str

    def snapshot(self) -> Snapshot: ...

    def close(self) -> None: ...


class Fitted:
    """Lines made for the width Rich draws them at (the widget's, known only then; again at each
    resize), so no line is cut where the panels assumed another width."""

    def __init__(self, make: Callable[[int], list[Text]]) -> None:
        self.make = make

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> Iterator[Text]:
        yield from self.make(options.max_width)


class StatusApp(App[None]):
    TITLE = "Serra status"
    ENABLE_COMMAND_PALETTE = False
    CSS = """
    #title { height: 1; background: $primary-background; color: $text; padding: 0 1; }
    #tabs { height: 1; padding: 0 1; }
    #body { height: 1fr; padding: 0 1; scrollbar-size-vertical: 1; }
    """
    BINDINGS = [
        Binding("q", "quit", "quit"),
        Binding("ctrl+c", "quit", "quit", show=False, priority=True),
        Binding("1,g", "panel('greenhouse')", "greenhouse"),
        Binding("2,k", "panel('kits')", "kits"),
        Binding("3,w", "panel('gateway')", "gateway"),
        Binding("tab", "next_panel", "next panel", show=False, priority=True),
        Binding("left,p", "greenhouse(-1)", "prev gh"),
        Binding("right,n", "greenhouse(1)", "next gh"),
        Binding("r", "refresh", "refresh"),
    ]

    def __init__(self, source: Source, interval: float = 2.0, panel: str = "greenhouse",
                 greenhouse: str | None = None) -> None:
        super().__init__()
        self.source, self.interval = source, interval
        self.panel = panel if panel in render.PANELS else "greenhouse"
        self.want_greenhouse = greenhouse
        self.gh = 0
        self.snap: Snapshot | None = None
        self.error = ""
        self.refreshes = 0  # snapshots shown (tests wait on it)
        self._busy = threading.Lock()

    def compose(self) -> ComposeResult:
        yield Static(Text("Serra status: reading…"), id="title")
        yield Static(id="tabs")
        with VerticalScroll(id="body"):
            yield Static(Text(f"reading {self.source.label} …"), id="content")
        yield Footer()

    def on_mount(self) -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGHUP):  # a closed SSH session: restore, then exit
            try:
                loop.add_signal_handler(sig, self.exit)
            except (NotImplementedError, RuntimeError, ValueError):
                pass
        self.query_one("#body").focus()
        self.draw()
        self.load()
        self.set_interval(self.interval, self.load)

    # -- data ---------------------------------------------------------------------------------
    @work(thread=True, exit_on_error=False)
    def load(self) -> None:
        """Take a snapshot in a thread (the source may block); skipped while one is running."""
        if not self._busy.acquire(blocking=False):
            return
        try:
            snap, err = self.source.snapshot(), ""
        except Exception as e:  # a store moved away, a network error: say it, keep going
            snap, err = None, f"{type(e).__name__}: {e}"
        finally:
            self._busy.release()
        self.call_from_thread(self.show, snap, err)

    def show(self, snap: Snapshot | None, err: str = "") -> None:
        if snap is not None:
            self.snap = snap
            if self.want_greenhouse is not None:
                names = [g.name for g in snap.greenhouses]
                if self.want_greenhouse in names:
                    self.gh = names.index(self.want_greenhouse)
                    self.want_greenhouse = None
        self.error = err
        self.refreshes += 1
        self.draw()

    # -- drawing --------------------------------------------------------------------------------
    def draw(self) -> None:
        tabs = Text()
        for i, p in enumerate(render.PANELS, 1):
            label = f" {i} {p} "
            tabs.append(label, "reverse bold" if p == self.panel else "")
            tabs.append(" ")
        if self.snap is not None and len(self.snap.greenhouses) > 1 and self.panel == "greenhouse":
            tabs.append("←/→ greenhouse", "dim")
        self.query_one("#tabs", Static).update(tabs)
        if self.snap is None:
            msg = f"cannot read {self.source.label}: {self.error}" if self.error else \
                f"reading {self.source.label} …"
            self.query_one("#content", Static).update(Text(msg, "bold red" if self.error else ""))
            return
        snap, panel, gh = self.snap, self.panel, self.gh
        self.query_one("#title", Static).update(Fitted(lambda w: [render.title(snap, panel, gh, w)]))
        head = []
        stale = time.time() - snap.wall
        if stale > max(5 * self.interval, 10):
            head.append(Text(f"snapshot {stale:.0f} s old", "yellow"))
        if self.error:
            head.append(Text(f"refresh failed (showing the last snapshot): {self.error}",
                             "bold red"))
        self.query_one("#content", Static).update(
            Fitted(lambda w: head + render.panel_lines(snap, panel, gh, w)))

    # -- actions --------------------------------------------------------------------------------
    def action_panel(self, name: str) -> None:
        self.panel = name
        self.query_one("#body", VerticalScroll).scroll_home(animate=False)
        self.draw()

    def action_next_panel(self) -> None:
        i = render.PANELS.index(self.panel)
        self.action_panel(render.PANELS[(i + 1) % len(render.PANELS)])

    def action_greenhouse(self, step: int) -> None:
        n = len(self.snap.greenhouses) if self.snap is not None else 0
        if n:
            self.gh = (self.gh + step) % n
        if self.panel != "greenhouse":
            self.panel = "greenhouse"
        self.draw()

    def action_refresh(self) -> None:
        self.load()

"""The status screen's Textual app, driven headless at 80×24 by its Pilot on a store filled in
process the way the service fills it (tests/status_store.py)."""

from __future__ import annotations

import asyncio
import re
import sqlite3
import time
from pathlib import Path

from gateway.status.app import StatusApp
from gateway.status.snapshot import Snapshot
from gateway.status.store_source import StoreSource
from gateway.store import Store
from tests.status_helpers import digest, fresh_status
from tests.status_store import Filled


# -- the app, headless at 80×24 ---------------------------------------------------------------------
def screen_text(app: StatusApp) -> str:
    return "\n".join(s.text for s in app.screen._compositor.render_strips())


async def _shown(app, pilot, *markers: str, what: str) -> str:
    """The screen once every one of ``markers`` is on it: panels are filled from snapshots taken
    in a thread and painted part by part, so a key's effect can show a few frames later on a
    busy machine (generous deadline)."""
    deadline = time.monotonic() + 60
    while not all(m in (text := screen_text(app)) for m in markers):
        assert time.monotonic() < deadline, f"{what}: {markers!r} not all shown in 60 s:\n{text}"
        await pilot.pause(0.05)
    return text


def _all(m: str | tuple[str, ...]) -> tuple[str, ...]:
    return (m,) if isinstance(m, str) else tuple(m)


async def _drive(source, keys_and_markers, first: str | tuple[str, ...], size=(80, 24)
                 ) -> list[str]:
    """Screens: the first one once ``first`` is on it (the first snapshot is counted before its
    panel is painted), then one after each (key, the text that shows it took effect)."""
    app = StatusApp(source, interval=0.5)
    shots: list[str] = []
    async with app.run_test(size=size) as pilot:
        deadline = time.monotonic() + 60
        while app.refreshes == 0:  # the first snapshot (taken in a thread)
            assert time.monotonic() < deadline, "no snapshot in 60 s"
            await pilot.pause(0.05)
        shots.append(await _shown(app, pilot, *_all(first), "q quit", what="the first snapshot"))
        for key, marker in keys_and_markers:
            await pilot.press(key)
            await pilot.pause()
            shots.append(await _shown(app, pilot, *_all(marker), "q quit", what=f"after {key!r}"))
        await pilot.press("q")
    assert app.return_code == 0
    return shots


class PinnedClock(StoreSource):
    """A store source whose wall clock stands at ``wall``: what the screen says of the
    heartbeat's age does not depend on how long a loaded machine takes to draw it."""

    def __init__(self, path: Path, wall: float) -> None:
        super().__init__(path)
        self.wall = wall

    def snapshot(self, wall: float | None = None) -> Snapshot:
        return super().snapshot(self.wall if wall is None else wall)


def test_app_at_80x24_switches_panels_and_quits(store: Filled) -> None:
    beat = fresh_status(store)
    src = PinnedClock(store.path, beat + 1.0)
    before = digest(store.path)
    try:
        # each screen is read once everything asserted below is painted
        steps = [("2", ("SILENT", "rain timeout", "bad_tag 3")),
                 ("3", ("Service    running · pid 4242", "Zenoh      up: 1 peer")),
                 ("g", ("Inside T  measured", "greenhouse north (1/1)"))]
        home, kits, gateway, back = asyncio.run(_drive(
            src, steps, ("greenhouse north (1/1)", "Inside T  measured", "Parameters (prototype",
                         "heat_source since")))
    finally:
        src.close()
    assert digest(store.path) == before  # the screen never writes
    for shot in (home, kits, gateway):
        lines = shot.splitlines()
        assert len(lines) == 24 and all(len(x) <= 80 for x in lines)
    assert "greenhouse north (1/1)" in home and "Inside T  measured" in home
    assert "Parameters (prototype" in home and "heat_source since" in home
    assert "q quit" in home.splitlines()[-1], home
    assert "SILENT" in kits and "rain timeout" in kits and "bad_tag 3" in kits
    assert "Service    running · pid 4242" in gateway and "Zenoh      up: 1 peer" in gateway
    assert "Inside T  measured" in back and "greenhouse north (1/1)" in back  # back again
    print("\n--- 80x24: greenhouse ---\n" + home + "\n--- kits ---\n" + kits +
          "\n--- gateway ---\n" + gateway)


def test_app_on_an_empty_store_and_with_the_link_down(store: Filled, tmp_path: Path) -> None:
    Store(tmp_path / "empty.db").close()
    src = StoreSource(tmp_path / "empty.db")
    try:
        (home, gw) = asyncio.run(_drive(src, [("w", "unknown: no status from a gateway")],
                                        "No greenhouse in this store yet."))
    finally:
        src.close()
    assert "No greenhouse in this store yet." in home
    assert "unknown: no status from a gateway" in gw
    beat = fresh_status(store, peers=0, waiting=("serra/f1/north/forecast",))
    src = PinnedClock(store.path, beat + 1.0)
    try:
        (_, gw) = asyncio.run(_drive(src, [("3", "DOWN: no peer or router connected")],
                                     "Inside T  measured"))
    finally:
        src.close()
    assert "DOWN: no peer or router connected" in gw


def test_app_keeps_the_last_snapshot_when_a_refresh_fails(store: Filled) -> None:
    class Flaky(StoreSource):
        calls = 0

        def snapshot(self, wall=None):
            self.calls += 1
            if self.calls > 1:
                raise sqlite3.OperationalError("disk I/O error")
            return super().snapshot(wall)

    src = Flaky(store.path)
    try:
        (_, again) = asyncio.run(_drive(src, [("r", "refresh failed")], "Inside T  measured"))
    finally:
        src.close()
    assert "refresh failed (showing the last snapshot): OperationalError: disk I/O" in again
    assert "Inside T  measured" in again


def test_a_wider_terminal_shows_whole_lines_and_a_narrower_one_cuts_them_at_a_word(
        store: Filled) -> None:
    """The panels were laid out for 78 columns whatever the terminal: at 120 a long line was
    still cut at 78, and at 60 Rich cut where the columns ran out, inside a number
    ("13.0..13…"). Now they are made for the width they are drawn at."""
    said = ("96 % of the radiation above 50 W m-2 is measured while the sun is below the horizon "
            "at latitude 34.85, longitude 5.73 (east positive)")
    run = {"when": store.now - 3600, "ok": True, "findings": 0, "note": "diagnosis of 1.8 days",
           "notes": [{"code": "site_time_mismatch", "level": "warning", "message": said}]}
    beat = fresh_status(store, diagnosis={"north": run})
    src = PinnedClock(store.path, beat + 1.0)
    try:
        (_, wide) = asyncio.run(_drive(src, [("3", "warning site_time_mismatch")],
                                       "Inside T  measured", size=(120, 24)))
        (narrow, narrow_gw) = asyncio.run(_drive(src, [("3", "warning site_time_")],
                                                 ("Inside T", "T in "), size=(60, 24)))
    finally:
        src.close()
    lines = wide.splitlines()
    assert len(lines) == 24 and all(len(x) <= 120 for x in lines)
    assert lines[0].rstrip().endswith("×300") and len(lines[0].rstrip()) > 100  # clock at right
    warning = next(x.rstrip() for x in lines if "warning site_time_mismatch" in x)
    assert 80 < len(warning) <= 120 and "is measured while the sun" in warning, warning
    for shot in (narrow, narrow_gw):
        lines = shot.splitlines()
        assert len(lines) == 24 and all(len(x) <= 60 for x in lines)
        assert not re.search(r"[\d.]…", shot), shot  # never half a number
    t_in = next(x.rstrip() for x in narrow.splitlines() if x.startswith(" T in "))
    assert re.search(r"( -?\d+\.\d\.\.-?\d+\.\d| …)$", t_in), t_in  # a whole range, or none
    print("\n--- 120x24: gateway ---\n" + wide + "\n--- 60x24: greenhouse ---\n" + narrow)


def _sparkline_columns(shot: str) -> int:
    """The columns of the T in sparkline on a greenhouse screen: from after its value cell to
    the range beside it, which starts under the header's "min..max"."""
    lines = shot.splitlines()
    head = next(x for x in lines if "latest" in x and "min..max" in x)
    t_in = next(x.rstrip() for x in lines if x.lstrip().startswith("T in "))
    rng = re.search(r" (-?\d+\.\d\.\.-?\d+\.\d)$", t_in)
    assert rng is not None, t_in  # the range is whole
    assert rng.start(1) == head.index("min..max"), (head, t_in)
    return rng.start(1) - 1 - (t_in.index("T in") + 20)  # "T in    " + value(10) + 2 spaces


def test_the_sparklines_take_the_columns_the_terminal_gives(store: Filled) -> None:
    """The sparklines were 36 bins at any width: a 120-column terminal left 40 columns blank
    beside them. Now they grow and shrink with the panel, column for column, the range beside
    them whole and under its header, and the "Inside T" pair alike."""
    beat = fresh_status(store)
    src = PinnedClock(store.path, beat + 1.0)
    try:
        shots = {w: asyncio.run(_drive(src, [], "Inside T  measured", size=(w, 24)))[0]
                 for w in (80, 120)}
    finally:
        src.close()
    columns = {w: _sparkline_columns(shot) for w, shot in shots.items()}
    assert columns[80] == 36  # the panel: 78 columns (80 less its padding), as --once
    assert columns[120] - columns[80] == 120 - 80, columns
    for w, shot in shots.items():
        measured = next(x for x in shot.splitlines() if x.lstrip().startswith("measured "))
        bars = re.search(r"measured   ([▁▂▃▄▅▆▇█ ]+) \d", measured)
        assert bars is not None and len(bars[1]) == columns[w], (w, measured)
    print("\n--- 120x24: greenhouse ---\n" + shots[120])

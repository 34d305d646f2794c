"""The store's capacity alarms are said when they start, a step worse, every 10 min while they
last and when they clear, not every maintenance round (10 s): a filling SD card wrote ``only N
MB free`` 360 times an hour into the journal on that card."""

from __future__ import annotations

import logging
import sqlite3
import subprocess
import sys
import threading
from contextlib import closing
from pathlib import Path

import pytest

from gateway.store import Store
from gateway.store.capacity import REMIND_S, Alarm, CapacityWatch
from gateway.store.keys import write_keys
from tests.gateway_harness import KEY, wait_for

DEADLINE = 120.0  # [s] for any one wait on a loaded machine
CLEARED = {"size": "size cleared", "free": "free cleared"}


def pad(db: Path, name: str, nbytes: int | None) -> None:
    """A meta row of ``nbytes`` (None: every pad gone and the file shrunk to what is left). On
    return the size is settled: the WAL checkpointed into the file and truncated (a checkpoint
    left to later grew the measured size, file + WAL, a second step at a time no test chooses)."""
    with closing(sqlite3.connect(db, timeout=60)) as c:
        if nbytes is None:
            c.execute("DELETE FROM meta WHERE name LIKE 'pad%'")
            c.commit()
            c.execute("VACUUM")
        else:
            c.execute("INSERT OR REPLACE INTO meta (name, value) VALUES (?, ?)",
                      (name, "x" * nbytes))
            c.commit()
        # busy while the service reads: tried again (its reads are short)
        wait_for(lambda: c.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()[0] == 0,
                 DEADLINE, "the WAL checkpointed")


def test_the_ingest_service_says_its_store_near_its_limit_once_worse_and_cleared(
        tmp_path: Path) -> None:
    db, keys = tmp_path / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY})
    Store(db).close()
    pad(db, "pad", 900_000)  # 1 MiB limit (the least accepted): the alarm at 80 %
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys", str(keys),
         "--listen", "127.0.0.1:0", "--max-db-mb", "1", "--maintenance-every", "0.05"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    assert proc.stderr is not None and proc.stdout is not None
    reader = threading.Thread(target=lambda: lines.extend(x.rstrip() for x in proc.stderr),
                              daemon=True)
    reader.start()

    def rounds(n: int) -> None:
        """``n`` maintenance rounds at least: each reads the changed keys file again."""
        for _ in range(n):
            seen = reloads()
            write_keys(keys, {7: KEY, 100 + seen: KEY})
            wait_for(lambda s=seen: reloads() > s or proc.poll() is not None, DEADLINE,
                     "a maintenance round")

    def reloads() -> int:
        return len([x for x in lines if "read again" in x])

    def said() -> list[str]:
        return [x.split(": ", 1)[1] for x in lines if "serra.store.retention" in x]

    try:
        assert "listening" in proc.stdout.readline()  # its keys read: a change is seen
        rounds(6)
        assert len(said()) == 1, said()
        pad(db, "pad2", 120_000)  # 11 % of the limit more: a step worse
        wait_for(lambda: any("(worse)" in x for x in lines) or proc.poll() is not None,
                 DEADLINE, "the worse line")
        # the step seen once, or twice if a round measured the WAL before the checkpoint (file +
        # WAL counted both: +11 %, then +22 % for a moment); then nothing while nothing changes
        n = len(said())
        rounds(6)
        assert len(said()) == n and 2 <= n <= 3, said()
        pad(db, "", None)  # (VACUUM copies the store into the WAL first: worse for a moment)
        wait_for(lambda: any("again" in x and "limit" in x for x in lines)
                 or proc.poll() is not None, DEADLINE, "the cleared line")
        rounds(3)
    finally:
        proc.terminate()
        code = proc.wait(timeout=DEADLINE)
        reader.join(timeout=DEADLINE)
        proc.stdout.close()
    assert code == 0, "\n".join(lines)
    lines_said = said()
    assert lines_said[0].startswith(f"database {db} is ") and lines_said[0].endswith(
        " % of its limit: shorten retention"), lines_said
    assert all(x.endswith(" % of its limit: shorten retention (worse)")
               for x in lines_said[1:-1]), lines_said
    assert lines_said[-1] == f"database {db} is below 80 % of its limit (1 MB) again", lines_said


def test_a_free_space_alarm_is_said_at_start_halved_every_10_min_and_cleared(
        caplog: pytest.LogCaptureFixture) -> None:
    t = [0.0]
    watch = CapacityWatch(clock=lambda: t[0])

    def free(mb: float, at: float) -> list[str]:
        t[0] = at
        caplog.clear()
        alarms = [Alarm("free", mb * 1e6, f"only {mb:g} MB free")] if mb >= 0 else []
        watch.check(alarms, CLEARED)
        return [r.getMessage() for r in caplog.records]

    with caplog.at_level(logging.WARNING, logger="serra.store.retention"):
        assert free(200, 0) == ["only 200 MB free"]
        assert all(free(mb, 10 * k) == [] for k, mb in enumerate((190, 150, 110, 101), 1))
        assert free(100, 60) == ["only 100 MB free (worse)"]  # halved since said
        assert free(99, 60 + REMIND_S - 1) == []
        assert free(99, 60 + REMIND_S) == ["only 99 MB free (for 10 min now)"]
        assert free(-1, 700) == ["free cleared"]
        assert free(-1, 710) == []
        assert free(120, 720) == ["only 120 MB free"]  # a new alarm: said at once

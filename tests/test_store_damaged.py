"""A damaged store file stops both services that keep it with one line and exit 65 (sysexits'
EX_DATAERR), which their units list in RestartPreventExitStatus= (tests/test_images_units.py):
it does not mend itself, so systemd restarting it every 5 s would meet the same error for
ever. Before, the ingest service exited 2 and the gateway 1, both restarted. The file is a real
store whose header was overwritten, as a failing card or a stray write leaves it."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import time
from contextlib import closing
from pathlib import Path

from gateway.store import Store
from gateway.store.keys import write_keys
from gateway.store.outage import EX_DAMAGED
from tests.gateway_harness import KEY, write_config

HINT = ("check it (sqlite3 {db} 'PRAGMA integrity_check'), then recover it ('.recover') or "
        "restore a copy, or move it aside (a new store is made), and start the service again")


def damage(db: Path) -> None:
    """A real store, its 100-byte header overwritten: SQLite says 'file is not a database'."""
    Store(db).close()
    with open(db, "r+b") as f:
        f.write(b"\xa5" * 100)


def damage_page(db: Path, table: str) -> None:
    """A real store, ``table``'s root page overwritten: its header is no b-tree page's, so SQLite
    says 'database disk image is malformed' (SQLITE_CORRUPT) when the table is read."""
    Store(db).close()
    with closing(sqlite3.connect(db)) as c:
        size = c.execute("PRAGMA page_size").fetchone()[0]
        root = c.execute("SELECT rootpage FROM sqlite_master WHERE name=?", (table,)).fetchone()[0]
    with open(db, "r+b") as f:
        f.seek((root - 1) * size)
        f.write(b"\xff" * 12)


def errors(text: str) -> list[str]:
    return [x for x in text.splitlines() if "error" in x.lower() or "Traceback" in x]


def test_the_ingest_service_stops_on_a_damaged_store_with_ex_dataerr(tmp_path: Path) -> None:
    db, keys = tmp_path / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY})
    damage(db)
    r = subprocess.run([sys.executable, "-m", "gateway.ingest.service", "--db", str(db),
                        "--keys", str(keys), "--listen", "127.0.0.1:0"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == EX_DAMAGED == os.EX_DATAERR == 65, r.stderr
    assert errors(r.stderr) == [
        f"error: {db}: the store is damaged (SQLite: file is not a database): stopping, nothing "
        f"more is acknowledged; " + HINT.format(db=db)], r.stderr
    assert r.stdout == ""  # never listening


def test_the_gateway_stops_on_a_damaged_store_with_ex_dataerr(tmp_path: Path) -> None:
    cfg = write_config(tmp_path, anchor=time.time(), scale=1.0)
    db = tmp_path / "gw.db"
    # (a file that is not SQLite at all is the config's error, 78: it may name a wrong file)
    damage_page(db, "meta")
    r = subprocess.run([sys.executable, "-m", "gateway", "run", "--config", str(cfg)],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == EX_DAMAGED, r.stderr
    [line] = errors(r.stderr)
    assert line.endswith(f"ERROR serra.gateway: {db}: the store is damaged (SQLite: database "
                         f"disk image is malformed): stopping, nothing more is acknowledged; "
                         + HINT.format(db=db)), r.stderr
    assert "serra-gateway ready" not in r.stdout

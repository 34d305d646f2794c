"""The daily diagnosis of the running gateway when the disk cannot be written, for real: the
gateway's file-size limit is lowered (``prlimit`` RLIMIT_FSIZE, soft only; CPython ignores
SIGXFSZ, so writes past it fail with EFBIG) as the round comes due, so the round's data file
cannot be written, then raised; lowered again while the ``diagnose`` subprocess runs, so its
findings and run cannot be kept, then raised. Before, either ended the scheduler's task and
with it the gateway (exit 1). Now the run is postponed, then held, with a line each, the gateway
keeps running, and the run is kept once, with the round's time, when the store writes again."""

from __future__ import annotations

import json
import os
import sqlite3
import time
from contextlib import closing
from pathlib import Path

from gateway.store import Store
from tests.gateway_harness import EPOCH, GatewayProcess, shifted_kit, wait_for, write_config
from tests.test_store_outage import LIMIT, alive, limit_writes, one_line

DEADLINE = 300.0  # [s] for any one wait on a loaded machine (the diagnosis takes a while)
DUE_S = 40.0  # [s] from writing the config to the round: the gateway is ready well before


def read(db: Path, sql: str) -> list[tuple]:
    with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as c:
        return c.execute(sql).fetchall()


def diagnose_child(pid: int) -> bool:
    """Whether the gateway ``pid`` runs its ``diagnose`` subprocess now."""
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            kids = Path(f"/proc/{pid}/task/{task}/children").read_text().split()
        except OSError:  # the thread ended meanwhile
            continue
        for kid in kids:
            try:
                argv = Path(f"/proc/{kid}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"diagnose" in argv:
                return True
    return False


def said(gw: GatewayProcess, needle: str) -> bool:
    return any(needle in x for x in gw.lines) or alive(gw.proc, gw.lines)


def test_a_round_waits_out_a_disk_it_cannot_write_and_the_gateway_goes_on(
        tmp_path: Path) -> None:
    db = tmp_path / "gw.db"
    end = shifted_kit(db)
    store = Store(db)  # the last round a day ago, less DUE_S: the next is due DUE_S from now
    store.set_meta("diagnosis_last", repr(end - 24 * 3600 + DUE_S))
    store.close()
    cfg = write_config(tmp_path, anchor=time.time() - (end - EPOCH), scale=1.0,
                       diagnosis="every_hours = 24\ndays = 2.0\nmin_days = 1.5\ntimeout_s = 600")
    gw = GatewayProcess(cfg, log_pipe=True)
    try:
        gw.start()
        assert gw.proc is not None
        limit_writes(gw.proc.pid, LIMIT)
        assert not read(db, "SELECT 1 FROM meta WHERE name='diagnosis_run/north'"), \
            "the round ran before the limit was lowered: raise DUE_S"
        wait_for(lambda: said(gw, "diagnosis postponed"), DEADLINE, "the run postponed")
        limit_writes(gw.proc.pid, None)
        wait_for(lambda: diagnose_child(gw.proc.pid) or alive(gw.proc, gw.lines), DEADLINE,
                 "the diagnose subprocess", every=0.02)
        limit_writes(gw.proc.pid, LIMIT)  # its data is written: now its findings cannot be
        wait_for(lambda: said(gw, "held until the store can be written"), DEADLINE,
                 "the finished run held")
        assert not read(db, "SELECT 1 FROM meta WHERE name='diagnosis_run/north'")
        limit_writes(gw.proc.pid, None)
        kept = wait_for(lambda: read(db, "SELECT value FROM meta WHERE name='diagnosis_run/north'"),
                        DEADLINE, "the held run kept")
        run = json.loads(kept[0][0])
        # kept with the round's time, in the same transaction
        last = read(db, "SELECT value FROM meta WHERE name='diagnosis_last'")
        assert float(last[0][0]) == run["when"]
        assert run["ok"] is True and run["note"].startswith("diagnosis of 1.8 days in "), run
        wait_for(lambda: said(gw, ": back, writes succeed again"), DEADLINE, "the back line")
        assert gw.stop() == 0, "\n".join(gw.lines[-20:])
    finally:
        gw.kill()
    lines = gw.lines
    postponed = one_line(lines, "diagnosis postponed")
    assert postponed.endswith(f"greenhouse north: diagnosis postponed, its data cannot be written "
                              f"to {tmp_path}/serra-" + postponed.split("/serra-")[1])
    assert "(File too large); tried again after 10 s, then less often (at most every 10 min)" \
        in postponed
    one_line(lines, "greenhouse north: diagnosis goes on, its data written")
    held = one_line(lines, "held until the store can be written")
    assert f"greenhouse north: the diagnosis run ({run['note']}): held until" in held
    # the store's own lines (the worker's status writes may have failed in the first phase too)
    assert any(f"{db}: file size limit reached (RLIMIT_FSIZE {LIMIT} bytes; " in x for x in lines)
    assert not [x for x in lines if "Traceback" in x or "part stopped" in x], lines
    assert read(db, "PRAGMA integrity_check") == [("ok",)]

"""A store that cannot be written, for real: the running service's file-size limit is lowered
(``prlimit`` RLIMIT_FSIZE, soft limit only so that the test can raise it again; CPython ignores
SIGXFSZ, so every write past the limit fails with EFBIG and SQLite says ``disk I/O error``), then
raised again. Both services that write the store — ``gateway.ingest.service`` and ``gateway
run`` — must say it in one line naming the file and the cause, ack nothing that was not
committed (the kit keeps its records and resends), keep running, tell systemd (STATUS=), and once
writes succeed say so and store every record exactly once; the live gateway's estimator steps
every minute once, none skipped. The logs come through pipes: a log file would hit the limit too.
"""

from __future__ import annotations

import os
import resource
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

from gateway.cloud.store import SqliteCloudStore
from gateway.cloud.subscriber import Subscriber
from gateway.status import snapshot as S
from gateway.status.messages import Messages
from gateway.store.keys import write_keys
from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, wait_for, write_config
from tests.tcpcut import TcpCut
from tests.test_ingest_crash import KEY, WINDOW, Sender
from tests.test_sdnotify import NotifySocket
from training.kitsim import KitClock

DEADLINE = 120.0  # [s] for any one wait on a loaded machine
LIMIT = 1024  # [bytes] below every file of the store: each write of a page fails
RATE = 200  # [records s-1] sent to the ingest service


def limit_writes(pid: int, limit: int | None) -> None:
    """Lower (``limit`` bytes) or lift (None) the process's file-size limit, soft only."""
    hard = resource.prlimit(pid, resource.RLIMIT_FSIZE)[1]
    resource.prlimit(pid, resource.RLIMIT_FSIZE,
                     (resource.RLIM_INFINITY if limit is None else limit, hard))


def q(db: Path, sql: str) -> list[tuple]:
    with sqlite3.connect(db) as c:
        return c.execute(sql).fetchall()


class Statuses:
    """Every STATUS= a service sent to its notify socket (read as the test goes)."""

    def __init__(self, sock: NotifySocket) -> None:
        self.sock, self.seen = sock, []

    def read(self) -> list[str]:
        while msg := self.sock.next(0):
            if "STATUS" in msg:
                self.seen.append(msg["STATUS"])
        return self.seen


class CountingSocket:
    """The sender's socket, counting the packets sent per record (seq)."""

    def __init__(self, sock, counts: dict[int, int]) -> None:
        self.sock, self.counts = sock, counts

    def sendto(self, data: bytes, addr: tuple[str, int]) -> int:
        seq = int.from_bytes(data[12:16], "big")
        self.counts[seq] = self.counts.get(seq, 0) + 1
        return self.sock.sendto(data, addr)

    def __getattr__(self, name: str):
        return getattr(self.sock, name)


def alive(proc: subprocess.Popen | None, lines: list[str]) -> bool:
    """False, so that a wait goes on; an AssertionError with its log once the service exited
    (what the services did before they waited out a failing store)."""
    if proc is None or proc.poll() is not None:
        code = None if proc is None else proc.returncode
        raise AssertionError(f"the service exited ({code}):\n" + "\n".join(lines[-20:]))
    return False


def one_line(lines: list[str], needle: str) -> str:
    [line] = [x for x in lines if needle in x]
    return line


def test_ingest_holds_the_kits_records_while_the_store_cannot_be_written(tmp_path: Path) -> None:
    db, keys = tmp_path / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY})
    sock = NotifySocket(str(tmp_path / "notify"))
    statuses = Statuses(sock)
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys", str(keys),
         "--listen", "127.0.0.1:0", "--maintenance-every", "0.3"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "NOTIFY_SOCKET": sock.name})
    lines: list[str] = []
    assert proc.stderr is not None and proc.stdout is not None
    reader = threading.Thread(target=lambda: lines.extend(x.rstrip() for x in proc.stderr),
                              daemon=True)
    reader.start()
    s = Sender()
    sends: dict[int, int] = {}  # seq -> packets sent
    s.sock = CountingSocket(s.sock, sends)  # type: ignore[assignment]
    try:
        host, port = proc.stdout.readline().split()[-1].rsplit(":", 1)
        addr = (host, int(port))
        wait_for(lambda: len(s.acked) >= 100 or s.pump(addr, 0.05, rate=RATE), DEADLINE,
                 "100 records acked")

        limit_writes(proc.pid, LIMIT)
        wait_for(lambda: any("file size limit" in x for x in lines) or alive(proc, lines)
                 or s.pump(addr, 0.05, rate=RATE), DEADLINE, "the store's failure in the log")
        # The kit's window fills; every record in it is resent 10 times (over 3 s: the held
        # batch is retried after 1 s and 2 s meanwhile): none is acked.
        wait_for(lambda: s.next - min(s.unacked, default=s.next) >= WINDOW
                 or s.pump(addr, 0.05, rate=RATE), DEADLINE, "the kit's window full")
        acked_in_outage, held = set(s.acked), set(s.unacked)
        sends.clear()
        wait_for(lambda: all(sends.get(q, 0) >= 10 for q in held) or alive(proc, lines)
                 or s.pump(addr, 0.05), DEADLINE, "every held record resent 10 times")
        assert s.acked == acked_in_outage and set(s.unacked) == held
        stored = {r[0] for r in q(db, "SELECT seq FROM samples")}
        assert s.acked <= stored, f"acked, not stored: {sorted(s.acked - stored)[:10]}"
        assert proc.poll() is None, "\n".join(lines)
        wait_for(lambda: any(x.startswith("STORE FAILING") for x in statuses.read()), DEADLINE,
                 "STATUS= to say the store fails")

        limit_writes(proc.pid, None)
        wait_for(lambda: s.pump(addr, 0.05) or (not s.unacked and s.acked >= set(range(s.next))),
                 DEADLINE, "every held record acked")
        wait_for(lambda: any(": back, writes succeed again" in x for x in lines), DEADLINE,
                 "the back line")
        wait_for(lambda: statuses.read()[-1] == f"udp {host}:{port}", DEADLINE,
                 "STATUS= back to what it serves")
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=DEADLINE)
        reader.join(timeout=DEADLINE)
        s.sock.close()
        sock.close()
    assert code == 0, "\n".join(lines)
    failed = one_line(lines, "file size limit")
    assert f"ERROR serra.store: {db}: file size limit reached (RLIMIT_FSIZE {LIMIT} bytes; " \
           "SQLite: disk I/O error) — records not acked, the kits keep them; retrying with " \
           "backoff (1 s doubling to every 10 s)" in failed
    one_line(lines, "back, writes succeed again")
    assert not [x for x in lines if "Traceback" in x or "store write of" in x], lines
    rows = q(db, "SELECT seq, count(*) FROM samples GROUP BY seq")
    assert {seq for seq, _ in rows} == set(range(s.next)) and {n for _, n in rows} == {1}
    assert q(db, "PRAGMA integrity_check") == [("ok",)]


def unsent(db: Path) -> int:
    return q(db, "SELECT count(*) FROM outbox WHERE sent IS NULL")[0][0]


def estimated_to(db: Path) -> float:
    return (q(db, "SELECT max(minute) FROM estimator_state") or [(None,)])[0][0] or 0.0


def test_live_gateway_waits_out_the_store_and_its_estimator_skips_no_minute(
        tmp_path: Path) -> None:
    """The cloud's link is cut before the store fails and restored while it fails: the
    publisher then puts the messages it held and cannot mark them sent, so it meets the
    failing store too (the cloud gets them while the outbox still holds them)."""
    clock = KitClock(300.0, EPOCH)
    db = tmp_path / "gw.db"
    cloud = SqliteCloudStore(tmp_path / "cloud.db")
    sock = NotifySocket(str(tmp_path / "notify"))
    statuses = Statuses(sock)
    kit = PyKit(7, sim_trace(), clock.now)
    gw = GatewayProcess(write_config(tmp_path, anchor=clock.anchor, scale=300.0), log_pipe=True,
                        env={"NOTIFY_SOCKET": sock.name})
    proxy = sub = None
    try:
        gw.start()
        assert gw.proc is not None
        proxy = TcpCut(int(gw.zenoh.rsplit(":", 1)[1]))
        sub = Subscriber(cloud, [proxy.endpoint])
        sub.start()
        wait_for(lambda: (estimated_to(db) and cloud.count() >= 5) or kit.pump(gw.udp),
                 DEADLINE, "the estimator's state saved, messages in the cloud")
        proxy.cut()
        wait_for(lambda: unsent(db) >= 5 or kit.pump(gw.udp), DEADLINE, "messages held")

        limit_writes(gw.proc.pid, LIMIT)
        wait_for(lambda: any("file size limit" in x for x in gw.lines)
                 or alive(gw.proc, gw.lines) or kit.pump(gw.udp), DEADLINE,
                 "the store's failure in the log")
        acked, first_held, held = set(kit.acked), kit.next, unsent(db)
        in_cloud = cloud.count()
        proxy.restore()
        # 20 records (20 simulated minutes) sent while it fails: none acked; the held messages
        # reach the cloud, the outbox cannot say so
        wait_for(lambda: (kit.next >= first_held + 20 and cloud.count() > in_cloud)
                 or alive(gw.proc, gw.lines) or kit.pump(gw.udp), DEADLINE,
                 "20 more records sent, held messages in the cloud")
        assert kit.acked - acked <= {r[0] for r in q(db, "SELECT seq FROM samples")}
        assert not {s for s in kit.acked if s >= first_held}, "acked while the store fails"
        assert unsent(db) == held
        wait_for(lambda: any(x.startswith("STORE FAILING") for x in statuses.read()), DEADLINE,
                 "STATUS= to say the store fails")

        last = heal(gw, kit, db, statuses)
        assert gw.stop() == 0
        outbox = {r[0] for r in q(db, "SELECT idem FROM outbox")}
        wait_for(lambda: sub.wait_idle(1.0) and cloud.count() >= len(outbox), DEADLINE,
                 "the cloud to have every message")
    finally:
        gw.kill()
        if sub is not None:
            sub.stop()
        if proxy is not None:
            proxy.close()
        kit.close()
        sock.close()
    messages = list(cloud.messages())
    cloud.close()
    # every message once (the repeats of those put again dropped), each sample's measurement
    assert {m.idem for m in messages} == outbox and len(messages) == len(outbox)
    measured = {m.idem for m in messages if m.kind == "measurement/inside"}
    check_gateway_after(db, gw.lines, last, len(measured))
    # the status screen over Zenoh reads the same from the messages
    screen = Messages()
    for m in messages:
        screen.add(m.key, m.payload)
    notes = screen.snapshot("zenoh", time.time(), True, S.Link()).notes
    [note] = [n for n in notes if n.startswith("store unwritable ")]
    assert ": file size limit reached (RLIMIT_FSIZE" in note


def heal(gw: GatewayProcess, kit: PyKit, db: Path, statuses: Statuses) -> int:
    """Lift the limit; wait for every record sent so far (returned: how many) to be acked, the
    back line, the estimator to catch up, STATUS= back, a status message that tells of the
    failure, the outbox drained."""
    assert gw.proc is not None
    limit_writes(gw.proc.pid, None)
    last = kit.next
    wait_for(lambda: kit.acked >= set(range(last)) or kit.pump(gw.udp), DEADLINE,
             "every held record acked")
    wait_for(lambda: any(": back, writes succeed again" in x for x in gw.lines), DEADLINE,
             "the back line")
    wait_for(lambda: estimated_to(db) >= EPOCH + 60 * (last - 2) or kit.pump(gw.udp),
             DEADLINE, "the estimator to catch up")
    wait_for(lambda: not statuses.read()[-1].startswith("STORE FAILING"), DEADLINE,
             "STATUS= without the store's failure")
    wait_for(lambda: q(db, "SELECT count(*) FROM outbox WHERE key LIKE '%/status' AND "
                       "payload LIKE '%storeLastFailure%'")[0][0] or kit.pump(gw.udp),
             DEADLINE, "a status message that tells of the failure")
    wait_for(lambda: not unsent(db) or kit.pump(gw.udp), DEADLINE, "the outbox to drain")
    return last


def check_gateway_after(db: Path, lines: list[str], last: int, measured: int) -> None:
    """The gateway's log, store and status screen once it has stopped."""
    failed = one_line(lines, "file size limit")
    assert f"ERROR serra.store: {db}: file size limit reached (RLIMIT_FSIZE {LIMIT} bytes; " \
           "SQLite: disk I/O error) — records not acked, the kits keep them; the estimators " \
           "and the messages wait; retrying with backoff" in failed
    one_line(lines, "back, writes succeed again")
    assert not [x for x in lines if "Traceback" in x or "stopped:" in x], lines
    rows = q(db, "SELECT seq, count(*) FROM samples GROUP BY seq")
    assert {seq for seq, _ in rows} >= set(range(last)) and {n for _, n in rows} == {1}
    assert measured == len(rows)
    # the estimator: each minute stepped once, none skipped, from its first to its last
    minutes = [t for (t,) in q(db, "SELECT DISTINCT t FROM estimates WHERE source='online' "
                                   "ORDER BY t")]
    assert minutes == [minutes[0] + 60 * k for k in range(len(minutes))]
    assert minutes[-1] >= EPOCH + 60 * (last - 2)
    assert q(db, "SELECT count(*) FROM (SELECT t, name FROM estimates WHERE source='online' "
                 "GROUP BY t, name HAVING count(*) > 1)") == [(0,)]
    assert q(db, "PRAGMA integrity_check") == [("ok",)]
    # the status screen says what the store went through
    screen = subprocess.run([sys.executable, "-m", "gateway", "status", "--db", str(db),
                             "--panel", "gateway", "--once"], capture_output=True, text=True,
                            timeout=DEADLINE)
    [note] = [x for x in screen.stdout.splitlines() if "store unwritable" in x]
    assert note.startswith("Note       store unwritable ") and ": file size limit reached" in note


def test_ingest_stops_when_its_store_file_is_deleted_and_acks_nothing_after(
        tmp_path: Path) -> None:
    """SQLite writes on into a deleted file (its commits lost when the process ends): the
    service checks the file after each commit, before the acks, and stops with one line."""
    (tmp_path / "state").mkdir()
    db, keys = tmp_path / "state" / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY})
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys", str(keys),
         "--listen", "127.0.0.1:0", "--maintenance-every", "0.3"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    s = Sender()
    try:
        host, port = proc.stdout.readline().split()[-1].rsplit(":", 1)
        addr = (host, int(port))
        wait_for(lambda: len(s.acked) >= 50 or s.pump(addr, 0.05, rate=RATE), DEADLINE,
                 "50 records acked")
        wait_for(lambda: not s.unacked or s.pump(addr, 0.05, rate=0), DEADLINE,
                 "every record sent acked (no new one sent)")
        acked = set(s.acked)
        db.unlink()
        # new records: the service stops, or (before the check) acks one of them
        wait_for(lambda: proc.poll() is not None or s.acked != acked
                 or s.pump(addr, 0.05, rate=RATE), DEADLINE, "the service to stop")
    finally:
        if proc.poll() is None:
            proc.kill()
        _, err = proc.communicate(timeout=DEADLINE)
        s.sock.close()
    assert s.acked == acked, f"acked after the deletion: {sorted(s.acked - acked)[:10]}"
    assert proc.returncode == 1, err
    lines = err.splitlines()
    line = one_line(lines, "deleted or replaced")
    assert f"ERROR serra.store: {db}: the store file was deleted or replaced while open: " \
           "stopping, nothing more is acknowledged" in line
    assert not [x for x in lines if "Traceback" in x], err

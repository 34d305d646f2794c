"""SIGTERM while the ingest service holds a batch it could not write: the shutdown's final drain
commits it and acknowledges every record in it on the still open socket, then closes. Before,
the transports were closed first, so each ack of the drain failed (``ack to ... failed: Bad
file descriptor``) and the kit resent records already stored to the next start (nothing lost,
but noise and duplicate work). The batch is held for real: the service's file-size limit is
lowered (RLIMIT_FSIZE, tests/test_store_outage.py) until its retries have backed off to 8 s,
then raised and SIGTERM sent at once, so the drain, not a retry, commits it."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

from gateway import protocol as p
from gateway.store.keys import write_keys
from tests.gateway_harness import wait_for
from tests.test_ingest_crash import KEY, Sender
from tests.test_store_outage import DEADLINE, LIMIT, alive, limit_writes, q

HELD = 40  # records sent while the store cannot be written
FAILED = "a write of the ingest failed"  # the outage's debug line of each failed attempt


def test_sigterm_while_a_batch_is_held_commits_and_acks_it_before_closing(tmp_path: Path) -> None:
    db, keys = tmp_path / "g.db", tmp_path / "keys"
    write_keys(keys, {7: KEY})
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.ingest.service", "--db", str(db), "--keys", str(keys),
         "--listen", "127.0.0.1:0", "-v"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    assert proc.stderr is not None and proc.stdout is not None
    reader = threading.Thread(target=lambda: lines.extend(x.rstrip() for x in proc.stderr),
                              daemon=True)
    reader.start()
    s = Sender()
    try:
        host, port = proc.stdout.readline().split()[-1].rsplit(":", 1)
        addr = (host, int(port))
        wait_for(lambda: len(s.acked) >= 10 or s.pump(addr, 0.05, rate=100), DEADLINE,
                 "the first records acked")
        limit_writes(proc.pid, LIMIT)
        first = s.next
        wait_for(lambda: s.next >= first + HELD or s.pump(addr, 0.05, rate=100), DEADLINE,
                 "records sent while the store fails")
        # no new records; resent while the held batch is retried after 1, 2, 4 and 8 s
        wait_for(lambda: sum(FAILED in x for x in lines) >= 4 or alive(proc, lines)
                 or s.pump(addr, 0.05, rate=0), DEADLINE, "the fourth failed attempt")
        held = set(s.unacked)
        assert held and not held & s.acked
        limit_writes(proc.pid, None)
        proc.send_signal(signal.SIGTERM)  # the next retry is 8 s away: the drain commits
        code = proc.wait(timeout=DEADLINE)
        reader.join(timeout=DEADLINE)
        acks = read_acks(s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        s.sock.close()
    assert code == 0, "\n".join(lines)
    assert sum(FAILED in x for x in lines) == 4, "a retry, not the drain, wrote the batch"
    assert held <= acks, f"stored at the shutdown, not acked: {sorted(held - acks)[:10]}"
    assert not [x for x in lines if "ack to" in x or "Traceback" in x], lines
    [stopped] = [x for x in lines if "ingest stopped; counters" in x]
    assert "'ack_send_failed'" not in stopped, stopped
    rows = q(db, "SELECT seq, count(*) FROM samples GROUP BY seq")
    assert {seq for seq, _ in rows} == set(range(s.next)) and {n for _, n in rows} == {1}


def read_acks(s: Sender) -> set[int]:
    """The acks already in the sender's socket (the service has exited: nothing more comes)."""
    seqs = set()
    while True:
        try:
            data = s.sock.recv(256)
        except BlockingIOError:
            return seqs
        except ConnectionRefusedError:  # an ICMP error of an earlier resend: the next datagram
            continue
        a = p.decode_ack(data, KEY)
        assert a.status == p.ACK_STORED, a
        seqs.add(a.seq)

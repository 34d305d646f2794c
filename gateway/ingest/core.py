"""Transport-independent ingest: validate, de-duplicate, batch, commit, then acknowledge.

A packet is acknowledged only after the transaction holding it has committed, so an ack always
means durable. Duplicates (resends after a lost ack) are acknowledged again without storing.

Boots are stored as the board's boot counter plus the boot base of its key (Store.boot_base):
a board reflashed with a new key (``python -m gateway keys rotate``) starts above everything
its old key stored. A device refused as a whole (an old boot: a reflashed board, or a replay)
is named in `refused` and in one log line with the command that recovers it.

The keys can change while running (``reload_keys``: the service reads the keys file again when
it changes): an added device is accepted from then on, a rotated key takes its boot base, a
removed device is refused as ``unknown_device``. Records already authenticated are committed and
acknowledged with the key they came under.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable, Hashable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from hmac import compare_digest
from pathlib import Path
from typing import TypeVar

from gateway import protocol as p
from gateway.ingest.counters import Counters, RateLimitedLog
from gateway.ingest.reports import KeysReloaded, Refusal, peer_text, spans
from gateway.store import Store, losses
from gateway.store.keys import key_id
from gateway.store.outage import Outage, cause

log = logging.getLogger("serra.ingest")

Send = Callable[[bytes, Hashable], None]
T = TypeVar("T")

# Sequence numbers older than max_seq - WINDOW are replays. The firmware ring holds far fewer
# unacknowledged records (128), so a genuine resend is always inside the window.
WINDOW = 1024
_HEADER = p.MAGIC + bytes([p.VERSION, p.TYPE_RECORD])


@dataclass(slots=True)
class _Dev:
    key: p.Mac
    base: int = 0  # added to the boot the board sends (boot base of its key)
    boot: int = -1  # as stored: board boot + base
    max_seq: int = -1
    seen: set[int] = field(default_factory=set)  # committed seqs of `boot` inside the window
    health: tuple[int, int, int] = (-1, -1, 0)  # latest health packet: boot, hseq, dropped


@dataclass(slots=True)
class _Pending:
    rec: p.Record
    t_recv: float
    waiters: list[tuple[Send, Hashable]]
    dev: _Dev  # the device state (key, boot base) the record was authenticated with


class IngestCore:
    def __init__(self, store: Store, keys: dict[int, bytes], *, max_pending: int = 50_000,
                 batch_delay: float = 0.0, alarm_fraction: float = 0.8,
                 keys_path: str | Path | None = None,
                 clock: Callable[[], float] = time.time,
                 on_commit: Callable[[int], None] | None = None,
                 outage: Outage | None = None) -> None:
        """``keys_path``: the keys file (named in the refusal's recovery command); ``clock``:
        receive time [unix s] (the live gateway's clock); ``on_commit(n)``: called on the event
        loop after each batch of n records is durable; ``outage``: where a store that cannot be
        written is said (gateway/store/outage.py)."""
        self.store = store
        self.outage = outage or Outage(store.path, "records not acked, the kits keep them")
        self.retry_s: float | None = None  # a batch is held: the writer tries again after this
        self.clock = clock
        self.on_commit = on_commit
        self.counters = Counters()
        self.rlog = RateLimitedLog(log)
        # A refused device is named once per 10 minutes, not once per packet.
        self.refusal_log = RateLimitedLog(log, interval=600.0, burst=1)
        self.keys_path = str(keys_path) if keys_path is not None else "KEYS_FILE"
        self.refused: dict[int, Refusal] = {}
        self.max_pending = max_pending
        self.alarm_at = int(max_pending * alarm_fraction)
        self.batch_delay = batch_delay
        self.keys = dict(keys)
        self.devs: dict[int, _Dev] = self._load_devs(self.keys)
        self._pending: dict[tuple[int, int, int], _Pending] = {}
        self._queue: list[tuple[int, int, int]] = []
        self._wake = asyncio.Event()
        # held by each commit, its acks included: the shutdown's drain waits for the one in flight
        self._committing = asyncio.Lock()
        # SQLite work runs in one dedicated thread so the event loop keeps receiving.
        self._exec = ThreadPoolExecutor(1, thread_name_prefix="serra-store")
        self.alarm = False
        self._rejected: deque[losses.Report] = deque()

    def _load_devs(self, keys: dict[int, bytes]) -> dict[int, _Dev]:
        """The receiving state of ``keys``' devices from the store (runs on the store's thread
        once the writer runs): boot base of each key, latest stored boot, its committed seqs."""
        devs = {d: _Dev(p.Mac(k), self.store.boot_base(d, key_id(k))) for d, k in keys.items()}
        for dev, h in self.store.health_states().items():
            if dev in devs:
                devs[dev].health = h
        for dev, st in self.store.device_states().items():
            d = devs.get(dev)
            if d is not None:
                d.boot, d.max_seq = st.boot, st.max_seq
                d.seen = self.store.stored_seqs(dev, st.boot, st.max_seq - WINDOW)
        return devs

    async def reload_keys(self, keys: dict[int, bytes]) -> KeysReloaded:
        """Take a new set of device keys without stopping (call on the event loop)."""
        fresh = {d: k for d, k in keys.items() if self.keys.get(d) != k}
        removed = tuple(sorted(set(self.keys) - set(keys)))
        # Committed rows are read after the queue is flushed, so no record of a rotated device
        # is missing from its new state's replay window.
        await self._commit(asyncio.get_running_loop())
        devs = await self.run_in_store_thread(self._load_devs, fresh)
        for d in removed:
            self.devs.pop(d, None)
        self.devs.update(devs)
        changed = KeysReloaded(tuple(sorted(d for d in fresh if d not in self.keys)),
                               tuple(sorted(d for d in fresh if d in self.keys)), removed)
        self.keys = dict(keys)
        return changed

    # -- receiving ------------------------------------------------------------------------
    def _reject(self, reason: str, detail: str, peer: Hashable, device: int | None = None) -> None:
        self.counters[reason] += 1
        self.rlog.warning(reason, "packet from %s rejected: %s %s", peer_text(peer), reason,
                          detail, device=device)

    def _refuse_old_boot(self, dev_id: int, d: _Dev, boot: int, peer: Hashable) -> None:
        """An authenticated record from a boot older than the latest stored: a board whose
        flash lost its boot counter (reflashed, replaced) or a replay. Either way nothing is
        stored nor answered; the farm is told which device and how to take it back."""
        self.counters["replay_old_boot"] += 1
        latest = d.boot - d.base
        cmd = f"python -m gateway keys rotate {dev_id} --keys {self.keys_path}"
        r = self.refused.get(dev_id)
        if r is None:
            r = self.refused[dev_id] = Refusal(dev_id, "replay_old_boot", 0, boot, latest, 0.0,
                                               cmd)
        r.count, r.boot, r.latest, r.last = r.count + 1, boot, latest, self.clock()
        self.refusal_log.warning(
            "replay_old_boot",
            "device %d refused (replay_old_boot): packet from %s carries boot %d, older than "
            "boot %d already stored, so its records are dropped unanswered. A board reflashed "
            "or replaced (its boot counter lost) looks like this, and so do replayed packets. "
            "To take the board back (stored data is kept): %s (the gateway reads the keys file "
            "again by itself) and put the printed line in the board's config.json", dev_id,
            peer_text(peer),
            boot, latest, cmd, device=dev_id)

    def handle(self, data: bytes, peer: Hashable, send: Send) -> None:
        """Process one datagram/frame; never raises on any input."""
        try:
            self._handle(data, peer, send)
        except Exception:  # a bug must not stop ingest; counted and logged
            self.counters["internal_error"] += 1
            log.exception("internal error on packet %s from %s", bytes(data[:80]).hex(),
                          peer_text(peer))

    def _handle(self, data: bytes, peer: Hashable, send: Send) -> None:
        if len(data) == p.RECORD_LEN and data[:4] == _HEADER:  # fast path: well framed
            dev_id = int.from_bytes(data[4:8], "big")
        elif p.is_health(data):
            return self._health(data, peer)
        else:
            try:
                dev_id = p.peek_device(data)
            except p.ProtocolError as e:
                return self._reject(e.reason, e.detail, peer)
        d = self.devs.get(dev_id)
        if d is None:
            return self._reject("unknown_device", f"device {dev_id}", peer, dev_id)
        if not compare_digest(d.key.tag(data[: p.RECORD_BODY_LEN]), data[p.RECORD_BODY_LEN :]):
            return self._reject("bad_tag", f"device {dev_id} (forged, corrupted, or the board's "
                                "key differs from the keys file)", peer, dev_id)
        try:
            rec = p.parse_fields(data)
        except p.ProtocolError as e:
            # Authenticated, so the firmware is told to drop the record instead of resending it.
            self._reject(e.reason, f"device {dev_id}: {e.detail}", peer, dev_id)
            boot, seq = int.from_bytes(data[8:12], "big"), int.from_bytes(data[12:16], "big")
            self._send(send, peer, p.encode_ack(dev_id, boot, seq, p.ACK_REJECTED,
                                                p.REASON_CODES[e.reason], d.key))
            # Kept in the store (its thread, in order with the batches): not a board loss.
            self._exec.submit(self._note_rejected, dev_id, boot + d.base, seq, e.reason,
                              self.clock())
            return None
        boot = rec.boot + d.base
        if boot < d.boot:
            return self._refuse_old_boot(dev_id, d, rec.boot, peer)
        if boot == d.boot:
            if rec.seq <= d.max_seq - WINDOW:
                return self._reject("replay_old_seq", f"device {dev_id} seq {rec.seq}", peer,
                                    dev_id)
            if rec.seq in d.seen:
                self.counters["duplicate"] += 1
                self._send(send, peer, p.encode_ack(dev_id, rec.boot, rec.seq, p.ACK_DUPLICATE,
                                                    0, d.key))
                return None
        k = (dev_id, boot, rec.seq)
        pend = self._pending.get(k)
        if pend is not None:  # resent while its batch is being committed: ack after commit
            self.counters["duplicate"] += 1
            if (send, peer) not in pend.waiters:  # a held batch hears many resends
                pend.waiters.append((send, peer))
            return None
        if len(self._pending) >= self.max_pending:
            # No ack: the firmware keeps the record and resends it later.
            return self._reject("overload", f"{len(self._pending)} records waiting", peer)
        if boot > d.boot:
            d.boot, d.max_seq, d.seen = boot, -1, set()
            if self.refused:  # taken back (or it was a late packet of the previous boot)
                self.refused.pop(dev_id, None)
        if rec.seq > d.max_seq:
            d.max_seq = rec.seq
        self._pending[k] = _Pending(rec._replace(boot=boot) if d.base else rec, self.clock(),
                                    [(send, peer)], d)
        self._queue.append(k)
        self._wake.set()
        alarm = len(self._pending) >= self.alarm_at
        if alarm and not self.alarm:
            log.warning("ingest queue at %d/%d records: the store is not keeping up",
                        len(self._pending), self.max_pending)
        self.alarm = alarm

    def _health(self, data: bytes, peer: Hashable) -> None:
        """A health packet: the board's own counters. Authenticated like a record; never
        acknowledged (the next one carries the totals again); taken only if newer than the
        latest taken, by (boot, hseq), so a replay cannot put old counters back."""
        dev_id = int.from_bytes(data[4:8], "big")
        d = self.devs.get(dev_id)
        if d is None:
            return self._reject("unknown_device", f"health packet of device {dev_id}", peer,
                                dev_id)
        try:
            p.verify_health(data, d.key)
            h = p.parse_health(data)
        except p.ProtocolError as e:
            return self._reject(e.reason, f"health packet of device {dev_id} {e.detail}", peer,
                                dev_id)
        boot = h.boot + d.base
        if boot < d.boot or (boot, h.hseq) <= d.health[:2]:
            return self._reject("health_replay", f"device {dev_id}: health packet boot {h.boot} "
                                f"#{h.hseq} not newer than the latest taken (boot "
                                f"{d.health[0] - d.base} #{d.health[1]}) nor records' boot", peer,
                                dev_id)
        before = d.health[2] if d.health[0] == boot else 0
        d.health = (boot, h.hseq, h.dropped)
        self.counters["health"] += 1
        if h.dropped > before:
            log.warning("device %d boot %d reports %d records dropped from its ring (full %d, "
                        "too old %d; %d since its previous health packet)", dev_id, boot,
                        h.dropped, h.dropped_full, h.dropped_old, h.dropped - before)
        self._exec.submit(self._note_health, h, boot, self.clock())
        return None

    def _note_health(self, h: p.BoardHealth, boot: int, t: float) -> None:
        try:
            self.store.note_health(h, boot, t)
        except Exception as e:  # the next packet carries the same totals
            self._note_failed(e, f"the health packet of device {h.device_id}")

    def _send(self, send: Send, peer: Hashable, pkt: bytes) -> None:
        try:
            send(pkt, peer)
        except Exception as e:  # a lost ack only costs a resend
            self.counters["ack_send_failed"] += 1
            self.rlog.warning("ack_send_failed", "ack to %s failed: %s", peer_text(peer), e)

    def _note_rejected(self, dev_id: int, boot: int, seq: int, reason: str, t: float) -> None:
        """On the store's thread: remember a rejected record, so it is not counted lost."""
        try:
            # counted on the event loop at the next commit (deque.append is thread-safe)
            self._rejected.append(self.store.note_rejected(dev_id, boot, seq, reason, t))
        except Exception as e:  # at worst the record is later counted lost
            self._note_failed(e, f"rejected record device {dev_id} boot {boot} seq {seq}")

    def _note_failed(self, e: Exception, what: str) -> None:
        """A note that could not be kept: a store fault is the outage's (one line for all)."""
        if cause(e, self.store.path) is not None:
            self.outage.failed("ingest", e)
        else:  # (a damaged file: the next batch's write stops the service)
            log.error("could not keep %s: %s: %s", what, type(e).__name__, e)

    def _lost(self, report: losses.Report) -> None:
        """Count and log the records the boards lost that have just become final."""
        if report.lost:
            self.counters["lost_on_board"] += report.lost
        for line in losses.lines(report.gaps):
            log.warning("%s", line)

    # -- committing -----------------------------------------------------------------------
    async def run_writer(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            if self.batch_delay:
                await asyncio.sleep(self.batch_delay)  # let a batch build up: fewer commits
            self._wake.clear()
            await self._commit(loop)
            if self.retry_s is not None:  # the store failed: the held batch is tried again
                await asyncio.sleep(self.retry_s)
                self._wake.set()

    async def _commit(self, loop: asyncio.AbstractEventLoop) -> None:
        async with self._committing:
            await self._commit_queue(loop)

    async def _commit_queue(self, loop: asyncio.AbstractEventLoop) -> None:
        keys, self._queue = self._queue, []
        if not keys:
            return
        items = [(self._pending[k].rec, self._pending[k].t_recv) for k in keys]
        report = losses.Report()
        try:
            await loop.run_in_executor(self._exec, self._write, items, report)
        except Exception as e:
            # Nothing acknowledged, nothing lost: the senders still hold these records.
            self.counters["store_error"] += len(keys)
            # a damaged or deleted file raises StoreDamaged here: the service stops
            self.retry_s = self.outage.failed("ingest", e)
            if self.retry_s is not None:  # held (a resend joins it), written after the backoff
                self._queue = keys + self._queue
                return
            log.error("store write of %d records failed (%s): %s; none acknowledged, the boards "
                      "keep them and resend", len(keys), spans(keys), e)
            for k in keys:
                self._pending.pop(k, None)
            return
        self.retry_s = None
        self.outage.ok("ingest")
        self.counters["stored"] += len(keys)
        while self._rejected:
            self._lost(self._rejected.popleft())
        self._lost(report)
        for k in keys:
            pend = self._pending.pop(k)
            d = pend.dev
            if d.boot == k[1]:
                d.seen.add(k[2])
                if len(d.seen) > 2 * WINDOW:
                    lo = d.max_seq - WINDOW
                    d.seen = {s for s in d.seen if s > lo}
            ack = p.encode_ack(k[0], k[1] - d.base, k[2], p.ACK_STORED, 0, d.key)
            for send, peer in pend.waiters:
                self._send(send, peer, ack)
        if self.on_commit is not None:
            try:
                self.on_commit(len(keys))
            except Exception:  # a listener's bug must not stop ingest
                log.exception("on_commit listener failed")

    def _write(self, items: list[tuple[p.Record, float]], report: losses.Report) -> None:
        """On the store's thread: the batch, committed in the file that was opened (checked
        before any ack: a deleted store would swallow it)."""
        self.store.write_batch(items, report)
        self.store.check_file()

    async def drain(self) -> None:
        """Commit whatever is queued (graceful shutdown), after the writer's commit in flight
        and its acks: the transports are closed next."""
        await self._commit(asyncio.get_running_loop())

    def run_in_store_thread(self, fn: Callable[..., T], *args: object) -> asyncio.Future[T]:
        """Run store work (aggregation, retention) on the thread that owns the connection."""
        return asyncio.get_running_loop().run_in_executor(self._exec, fn, *args)

    def close(self) -> None:
        self._exec.shutdown(wait=True)

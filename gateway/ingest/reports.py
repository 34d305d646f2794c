"""What the ingest core reports: refused devices, a keys file read again, the records of a batch
and a packet's sender as log lines name them."""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass


def spans(keys: list[tuple[int, int, int]]) -> str:
    """The records of a batch as a log line names them: ``device 7 seq 3-5, device 9 seq 12``
    (keys are (device, boot, seq); the seqs' range per device)."""
    seqs: dict[int, list[int]] = {}
    for dev, _, seq in keys:
        seqs.setdefault(dev, []).append(seq)
    return ", ".join(f"device {d} seq {min(v)}" + (f"-{max(v)}" if max(v) > min(v) else "")
                     for d, v in sorted(seqs.items()))


def peer_text(peer: Hashable) -> str:
    """Where a packet came from, as a log line says it: ``192.168.4.7:5683`` for a UDP
    (host, port), ``[fe80::1]:5683`` for IPv6, the port's name for serial."""
    if isinstance(peer, tuple) and len(peer) >= 2 and isinstance(peer[0], str):
        host = f"[{peer[0]}]" if ":" in peer[0] else peer[0]
        return f"{host}:{peer[1]}"
    return str(peer)


@dataclass(slots=True)
class Refusal:
    """A device whose packets are refused as a whole, for the status screen and the logs;
    kept in IngestCore.refused until the device starts a boot newer than the latest stored."""

    device_id: int
    reason: str  # "replay_old_boot"
    count: int  # packets refused since the gateway started
    boot: int  # boot counter of the latest refused packet, as the board sent it
    latest: int  # the latest boot stored, in the board's counting (its key's)
    last: float  # unix time of the latest refused packet
    recovery: str  # the command that takes the board back


@dataclass(frozen=True)
class KeysReloaded:
    """What ``IngestCore.reload_keys`` changed (device ids)."""

    added: tuple[int, ...]
    rotated: tuple[int, ...]
    removed: tuple[int, ...]

    def __bool__(self) -> bool:
        return bool(self.added or self.rotated or self.removed)

    def __str__(self) -> str:
        parts = [f"{what} {', '.join(map(str, ids))}" for what, ids in
                 (("added", self.added), ("new key for", self.rotated),
                  ("removed", self.removed)) if ids]
        return "; ".join(parts) or "no change"

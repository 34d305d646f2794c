"""The kits panel: per kit its last record, records, losses, boot and channels, what its board
reports itself, and the gateway's packet counters (lines as :mod:`gateway.status.render` says)."""

from __future__ import annotations

from rich.text import Text

from gateway.status import snapshot as S
from gateway.status.formats import (
    ALARM,
    DIM,
    OK,
    WARN,
    WIDTH,
    duration,
    fitted,
    hhmm,
    wrapped,
)
from gateway.status.formats import line as _line


def _board_lines(b: S.BoardCounters, width: int) -> list[Text]:
    """What the board itself reported (its health packet), under the count the gateway infers:
    its drops are known at once, the inferred ones a seq span (512 records) later."""
    rssi = f" · wifi {b.rssi_dbm} dBm" if b.rssi_dbm is not None else ""
    errors = f" · {b.send_errors} send errors" if b.send_errors else ""
    text = (f"board says ({hhmm(b.reported)}): {b.dropped} dropped from its ring this boot "
            f"(full {b.dropped_full}, too old {b.dropped_old}){errors}{rssi} · heap "
            f"{b.heap_free // 1024} kB free · up {duration(b.uptime_s)}")
    return wrapped(text, "     ", WARN if b.dropped or b.send_errors else DIM, width)


def kit_lines(snap: S.Snapshot, width: int = WIDTH) -> list[Text]:
    out = [_line(("kit   greenhouse        last record               records  lost  boot  state",
                  DIM))]
    for k in snap.kits:
        where = ", ".join(k.greenhouses) if k.greenhouses else "(unassigned)"
        age = (snap.now - k.last_seen) if snap.now is not None and k.last_seen is not None else None
        seen = f"{hhmm(k.last_seen)} ({duration(age)} ago)" if k.last_seen is not None else "never"
        boot = "—" if k.boot is None else str(k.boot)
        state = ("REFUSED", ALARM) if k.refused else ("SILENT", ALARM) if k.silent else ("ok", OK)
        out.append(_line(f"{k.device_id:>4}  {where[:16]:<16}  {seen:<24} {k.records:>8}",
                         (f"{k.lost:>6}", WARN if k.lost else DIM), f"  {boot:>4}  ", state))
        bad = {c: s for c, s in k.channels.items() if s != "ok"}
        if not k.channels:
            chans = ("     no record yet", DIM)
        elif not bad:
            chans = (f"     all {len(k.channels)} channels ok", DIM)
        else:
            chans = ("     " + " · ".join(f"{c} {s}" for c, s in bad.items())
                     + " (others ok)" * (len(bad) < len(k.channels)), WARN)
        extra = (f"; stored as boot {k.stored_boot} (key rotated)"
                 if k.stored_boot is not None and k.boot is not None and k.stored_boot != k.boot else "")
        out.append(_line(chans, extra))
        if k.lost:
            # the board made them but never got them stored (gateway/store/losses.py)
            out.append(_line((f"     {k.lost} record{'s' * (k.lost > 1)} lost on the board"
                              ": ring overflow or restart, never stored",
                              WARN)))
        if k.board is not None:
            out += _board_lines(k.board, width)
        if k.refused:
            out += wrapped("refused: " + k.refused, "     ", ALARM, width)
    if not snap.kits:
        out.append(_line(("no kit has sent a record yet", WARN)))
    out.append(_line(""))
    out += _ingest_lines(snap.gateway, snap.now, width)
    return fitted(out, width)


def _ingest_lines(gw: S.Gateway, now: float | None, width: int) -> list[Text]:
    """The gateway's packet counters, said as of when it wrote them: it does every 5 wall s (10
    minutes on a 120× demo clock), so "stored" trails the records column, read from the store
    at each refresh, by the records of that while; said, it does not read as data lost."""
    if not gw.ingest:
        return [_line("Packets    ", ("no counters (the gateway writes them while it runs)", DIM))]
    rej = gw.rejects
    head = _line(f"Packets    {gw.ingest.get('stored', 0)} stored · {gw.ingest.get('duplicate', 0)} "
                 "duplicates · ", (f"{sum(rej.values())} rejected", WARN if rej else OK),
                 *([(f" · {lost} lost on the boards", WARN)]
                   if (lost := gw.ingest.get("lost_on_board", 0)) else []))
    when = ""
    if gw.ingest_t is not None:
        ago = f" ({duration(now - gw.ingest_t)} ago)" if now is not None else ""
        when = f", as of its status at {hhmm(gw.ingest_t)}{ago}"
    out = [head, _line(("           since the gateway started" + when, DIM))]
    items = [f"{k} {v}" for k, v in sorted(rej.items(), key=lambda kv: -kv[1])]
    line = "  by reason:"
    for it in items:
        if len(line) + len(it) + 3 > width:
            out.append(_line((line, WARN)))
            line = "            "
        line += f" {it} ·"
    if items:
        out.append(_line((line.rstrip(" ·"), WARN)))
    return out

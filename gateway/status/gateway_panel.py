"""The gateway panel: the service, its clock, the Zenoh link, the outbox, the store and disk,
each greenhouse's last diagnosis run and the notes (lines as :mod:`gateway.status.render`
says)."""

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
    size,
    stamp,
    tail,
)
from gateway.status.formats import line as _line


def _on_the_scaled_clock(gw: S.Gateway) -> str:
    """Under the TEST/DEMO clock line: which times are on it (every one on the screen but the
    service's uptime and heartbeat, which are the process's, wall) and the uptime on it (a
    linear clock: wall uptime × scale), to set beside the data's times and spans."""
    if gw.running and gw.pid is not None and gw.uptime_s is not None:
        return (f"           up {duration(gw.uptime_s * gw.clock_scale)} on it; every other time "
                "on the screen is on it")
    return "           every time on the screen but the heartbeat's is on it"


def gateway_lines(snap: S.Snapshot, width: int = WIDTH) -> list[Text]:
    gw = snap.gateway
    scaled = gw.clock_scale != 1.0
    wall = " (wall clock)" if scaled else ""  # the process's own times, beside a scaled clock
    if gw.running is None:
        svc = _line("Service    ", ("unknown: no status from a gateway", WARN))
    elif not gw.running and gw.pid is None:
        svc = _line("Service    ", ("NO ANSWER", ALARM), " to history queries")
    elif gw.running and gw.pid is None:  # over Zenoh: it answers; uptime as of its status
        svc = _line("Service    ", ("answering", OK), f" · up {duration(gw.uptime_s)} at its last "
                    "status message")
    elif gw.running:
        svc = _line("Service    ", ("running", OK), f" · pid {gw.pid} · up {duration(gw.uptime_s)}"
                    f" · heartbeat {duration(gw.heartbeat_age_s)} ago{wall}")
    else:
        svc = _line("Service    ", ("NOT RUNNING", ALARM),
                    f" · last heartbeat {duration(gw.heartbeat_age_s)} ago{wall}")
    out = [svc]
    clock = f"Clock      {stamp(snap.now, seconds=True)}"
    if scaled:
        out.append(_line(clock, (f" · TEST/DEMO clock {gw.clock_scale:g}× the wall clock", WARN)))
        out.append(_line(_on_the_scaled_clock(gw)))
    else:
        out.append(_line(clock))
    lk = gw.link
    style = DIM if not lk.enabled or lk.up is None else OK if lk.up else ALARM
    first, *more = (lk.summary or "?").split("; ")
    out.append(_line("Zenoh      ", (first, style)))
    out += [_line(("           " + m, style)) for m in more]
    detail = []
    if lk.endpoints:
        detail.append("listening on " + ", ".join(lk.endpoints))
    if lk.published is not None:
        detail.append(f"{lk.published} messages put")
    if detail:
        out.append(_line("           " + " · ".join(detail)))
    ob = gw.outbox
    if ob.pending is None:
        out.append(_line("Outbox     ", ("unknown", DIM)))
    else:
        oldest = f" since {stamp(ob.oldest_t)}" if ob.pending and ob.oldest_t else ""
        limits = f" · alarm at {ob.alarm_at} of {ob.max}" if ob.alarm_at is not None else ""
        text = f"{ob.pending} waiting{oldest}{limits}"
        out.append(_line("Outbox     ", ("ALARM: " + text, ALARM) if ob.alarm else
                         (text, WARN if ob.pending else OK)))
    d = gw.disk
    if d.store_bytes is not None or d.free_bytes is not None:
        used = (f" · disk {size(d.free_bytes)} free of {size(d.total_bytes)} "
                f"({100 * (1 - d.free_bytes / d.total_bytes):.0f} % used)"
                if d.free_bytes is not None and d.total_bytes else "")
        out.append(_line(f"Store      {size(d.store_bytes)}{used}"))
        if d.path:
            out.append(_line((f"           {tail(d.path, width - 11)}", DIM)))
    out += _diagnosis_lines(gw)
    for n in snap.notes:
        out.append(_line(("Note       " + n, WARN)))
    out.append(_line((f"Source     {tail(snap.source, width - 11)}", DIM)))
    return fitted(out, width)


SHOWN_WARNINGS = 3
"""A run's warnings shown on the gateway panel, one line each (the rest counted)."""


def _diagnosis_lines(gw: S.Gateway) -> list[Text]:
    """Each greenhouse's last run; under it, only when it has any, its warnings (code and
    the start of the message; the whole message is in the gateway's log)."""
    out = []
    for name, d in sorted(gw.diagnosis.items()):
        out.append(_line(f"Diagnosis  {name}: {d.words}"))
        for code, message in d.warnings[:SHOWN_WARNINGS]:
            out.append(_line(("           warning ", WARN), (code, f"bold {WARN}"),
                             (f": {message}", WARN)))
        if len(d.warnings) > SHOWN_WARNINGS:
            more = len(d.warnings) - SHOWN_WARNINGS
            out.append(_line((f"           and {more} more warning{'s' * (more > 1)} "
                              "(the gateway's log)", WARN)))
    return out

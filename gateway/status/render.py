"""A :class:`Snapshot` → lines of text, one list per panel (greenhouse, kits, gateway).

Lines are rich ``Text`` (styles mark alarms and silences); ``plain()`` joins them without any
style for ``--once``. Every line is cut to the panel's ``width`` (``formats.fit``: at a word, never
inside a number): ``WIDTH``, 78 columns, for ``--once`` and an 80-column terminal; the screen
gives its own, so a wider terminal shows whole lines and a narrower one cuts them cleanly.
"""

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
    fit,
    fitted,
    hhmm,
    number,
    size,
    sparkline,
    stamp,
    tail,
    wrapped,
)
from gateway.status.formats import line as _line

CHANNELS = (  # channel, label, unit, format
    ("t_in", "T in", "°C", "{:.1f}"), ("rh_in", "RH in", "%", "{:.0f}"),
    ("t_out", "T out", "°C", "{:.1f}"), ("rh_out", "RH out", "%", "{:.0f}"),
    ("i_glob", "I glob", "W/m²", "{:.0f}"), ("wind", "wind", "m/s", "{:.1f}"),
    ("rain", "rain", "", "{:.0f}"))


# -- a channel's value (the small formats are in formats.py) ---------------------------------
def _channel_value(ch: str, v: float | None, fmt: str) -> str:
    if v is None:
        return "—"
    if ch == "rain":
        return "wet" if v > 0 else "dry"
    return fmt.format(v)


# -- panels --------------------------------------------------------------------------------------
def title(snap: S.Snapshot, panel: str, gh: int = 0, width: int = WIDTH) -> Text:
    """One line: farm, what is shown, the gateway clock (at the right of ``width``)."""
    where = f"farm {snap.farm}" if snap.farm else "Serra"
    if panel == "greenhouse" and snap.greenhouses:
        g = snap.greenhouses[gh % len(snap.greenhouses)]
        what = f"greenhouse {g.name} ({gh % len(snap.greenhouses) + 1}/{len(snap.greenhouses)})"
    else:
        what = panel
    clock = stamp(snap.now)
    if snap.gateway.clock_scale != 1.0:
        clock += f" ×{snap.gateway.clock_scale:g}"
    return fit(_line(f"{where} · {what}", " " * max(1, width - len(where) - len(what) - 3
                                                     - len(clock)), (clock, DIM)), width)


def greenhouse_lines(snap: S.Snapshot, index: int, width: int = WIDTH) -> list[Text]:
    return fitted(_greenhouse_lines(snap, index, spark_columns(width)), width)


def spark_columns(width: int) -> int:
    """The sparklines' columns on a panel ``width`` wide: 36 at ``WIDTH`` (78), one more or one
    less for each column more or less, from 12 to the sources' bins (the range beside them and
    the lines under them stay whole on a narrow terminal; a wide one shows more of the day)."""
    return max(12, min(36 + width - WIDTH, S.FINE_BINS))


def _spark(series: S.Series | None, columns: int, lo: float | None = None,
           hi: float | None = None) -> str:
    return f"{sparkline(series, lo, hi):<{columns}}"


def _greenhouse_lines(snap: S.Snapshot, index: int, columns: int = 36) -> list[Text]:
    if not snap.greenhouses:
        where = " in this store" if snap.source.startswith("store") else ""  # over Zenoh: none heard of
        return [_line((f"No greenhouse{where} yet.", WARN))] + [_line(n) for n in snap.notes]
    g = snap.greenhouses[index % len(snap.greenhouses)]
    state = g.state or "?"
    # worded to fit 78 columns with the default model and "waiting for data" (with the word
    # "model" and "in, 7 out" the kits were cut off); a shared kit as the kits panel says it
    kits = (f"kit {g.inside_device} in+out" if g.inside_device == g.outside_device else
            f"kit {g.inside_device} in, {g.outside_device} out")
    head = _line((g.name, "bold"), f"  {g.model} · estimator ",
                 (state, OK if state == "running" else WARN), f" · {kits}")
    some = next(iter(g.series.values()), None)
    span = duration(some.end - some.start) if some is not None else "24 h"
    label = f"last {span}"
    # "latest" over the values' right edge, the span over the sparklines, min..max over the ranges
    lines = [head, _line((f"            latest  {label:<{columns}} min..max", DIM))]
    for ch, label, unit, fmt in CHANNELS:
        side = g.inside if ch in ("t_in", "rh_in") else g.outside
        v = side.values.get(ch)
        st = side.status.get(ch, "")
        cell = _channel_value(ch, v, fmt) + (f" {unit}" if v is not None and unit else "")
        s = g.series.get(ch)
        s = s.rebinned(columns) if s is not None else None
        vr = S.value_range(s, v, side.t)
        rng = f"{number(vr[0], fmt)}..{number(vr[1], fmt)}" if vr is not None else "no data"
        style = WARN if st and st != "ok" else ""
        note = f" {st}" if st and st != "ok" else ""
        lines.append(_line(f"{label:<7} ", (f"{cell + note:>10}", style), "  ",
                           (_spark(s, columns), "cyan"), f" {rng}"))
    lines += _temperature_lines(g.temperature, columns)
    lines += _parameter_lines(g)
    lines.append(_ventilation_line(g.ventilation))
    lines += _finding_lines(g, snap.gateway.diagnosis.get(g.name))
    if g.inside.t is not None and S.silent(g.inside.t, snap.now):
        lines.insert(1, _line((f"inside kit {g.inside_device} silent for "
                               f"{duration((snap.now or 0) - g.inside.t)}", ALARM)))
    return lines


def _temperature_lines(t: S.Temperature, columns: int = 36) -> list[Text]:
    if t.t is None:
        return [_line("Inside T  ", ("no estimate yet (the estimator waits for final minutes)", WARN))]
    pred: list[str | tuple[str, str]] = [" · predicted ", (number(t.predicted), "bold"),
                                         " °C a minute ahead"] if t.predicted is not None else []
    out = [_line("Inside T  measured ", (number(t.measured), "bold"), " °C", *pred,
                 f" · at {hhmm(t.t)}")]
    if t.forecasts:
        fc = " · ".join(f"+{h} min {v:.2f}" for h, v in sorted(t.forecasts.items()))
        h = max(t.forecasts)
        out.append(_line(f"forecast  {fc} °C", (f" ({t.outlook})", DIM)))
        measured, ahead = (s.rebinned(columns) if s is not None else None
                           for s in (t.measured_series, t.forecast_series))
        lo, hi = _common_scale(measured, ahead)
        vr = S.value_range(t.measured_series, t.measured, t.t)
        rng = f"{number(vr[0], '{:.1f}')}..{number(vr[1], '{:.1f}')} °C" if vr else "no data"
        out.append(_line(f"{'measured':<9}  ", (_spark(measured, columns, lo, hi), "cyan"),
                         f" {rng}"))
        out.append(_line(f"{f'+{h} min':<9}  ", (_spark(ahead, columns, lo, hi), "magenta"),
                         f" at validity; next {hhmm(t.t + 60 * h)}"))
    skill = [s for s in t.skill if s.n]
    if skill:
        parts = "  ".join(f"{s.horizon_min}m {s.mae:.2f}|{s.persistence_mae:.2f}" for s in skill)
        out.append(_line(f"MAE       {parts} °C", ("  ours|persistence", DIM)))
    elif t.forecasts:
        out.append(_line(("MAE       none yet: a forecast is scored once its time has come", DIM)))
    return out


def _common_scale(*series: S.Series | None) -> tuple[float | None, float | None]:
    """The one scale both inside-temperature sparklines are drawn on (measured and forecast
    comparable by eye): the bins' of both, as drawn. For drawing only: the range printed beside
    "measured" is of the measurements (``S.value_range``). (None, None): neither has a bin."""
    bins = [x for s in series if s is not None for x in s.finite]
    return (min(bins), max(bins)) if bins else (None, None)


def _parameter_lines(g: S.GreenhouseView) -> list[Text]:
    if not g.parameters:
        return [_line("Parameters ", ("none estimated yet", DIM))]
    out = [_line(f"Parameters ({g.model}, online; ● inside its hard bounds)")]
    cells = []
    for p in g.parameters:
        pos = p.position
        if pos is None:
            bar = "  (no bounds)"
        else:
            k = min(max(int(round(pos * 9)), 0), 9)
            bar = "[" + "─" * k + "●" + "─" * (9 - k) + "]"
        edge = pos is not None and (pos <= 0.01 or pos >= 0.99)
        cells.append((f"{p.name:<10} {p.value:9.3g} ", (bar, WARN if edge else "")))
    for i in range(0, len(cells), 2):
        parts: list[str | tuple[str, str]] = []
        for a, b in cells[i:i + 2]:
            parts += [" " + a, b, "  "]
        out.append(_line(*parts))
    return out


def _ventilation_line(v: S.Ventilation) -> Text:
    if v.flow is None:
        none = "no virtual sensor" + (f": {v.why_none}" if v.why_none else "")
        return _line("Ventilation ", (none if not v.configured else
                                      "virtual sensor set, no estimate yet", DIM))
    flag = (" · inputs out of its range", WARN) if v.out_of_range else ""
    return _line(f"Ventilation {number(v.flow, '{:.3f}')} m³/s · heat loss "
                 f"{number(v.heat_loss, '{:.0f}')} W/m² at {hhmm(v.t)}", flag)


def _warned(d: S.Diagnosis | None) -> str | tuple[str, str]:
    """The last run's warnings, before its words (which a long note may cut): the figures are
    likely wrong. "" without any."""
    if d is None or not d.warnings:
        return ""
    codes = ", ".join(code for code, _ in d.warnings)
    n = len(d.warnings)
    return (f" · diagnosis warning{'s' * (n > 1)}: {codes}", WARN)


def _finding_lines(g: S.GreenhouseView, diagnosis: S.Diagnosis | None) -> list[Text]:
    run = f" ({diagnosis.words})" if diagnosis else ""
    if not g.findings:
        return [_line("Findings   ", ("none", DIM), _warned(diagnosis), run if diagnosis else
                      " (the diagnosis has not run yet: [diagnosis] every_hours)")]
    out = [_line(f"Findings   {len(g.findings)}", _warned(diagnosis), run)]
    for f in g.findings[-3:]:
        since = f"since {stamp(f.start)}" if f.start is not None else "since before the data"
        out.append(_line(" ", (f.effect, WARN), f" {since}, rev {f.revision}: {f.summary}"))
    return out


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


PANELS = ("greenhouse", "kits", "gateway")


def panel_lines(snap: S.Snapshot, panel: str, gh: int = 0, width: int = WIDTH) -> list[Text]:
    if panel == "greenhouse":
        return greenhouse_lines(snap, gh, width)
    if panel == "kits":
        return kit_lines(snap, width)
    return gateway_lines(snap, width)


def plain(snap: S.Snapshot) -> str:
    """Every panel, every greenhouse, as plain text (``--once``): no style, no escape code."""
    out: list[str] = []
    for i in range(max(len(snap.greenhouses), 1)):
        out += [title(snap, "greenhouse", i).plain, ""]
        out += [t.plain.rstrip() for t in greenhouse_lines(snap, i)] + [""]
    for panel in ("kits", "gateway"):
        out += [title(snap, panel).plain, ""] + [t.plain.rstrip() for t in panel_lines(snap, panel)]
        out.append("")
    return "\n".join(out).rstrip() + "\n"

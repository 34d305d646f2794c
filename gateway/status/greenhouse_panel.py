"""The greenhouse panel: one greenhouse's readings beside their day's sparklines, the inside
temperature measured, predicted and forecast with the forecasts' skill, the model parameters in
their bounds, the ventilation estimate and the findings (lines as :mod:`gateway.status.render`
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
    hhmm,
    number,
    sparkline,
    stamp,
)
from gateway.status.formats import line as _line

CHANNELS = (  # channel, label, unit, format
    ("t_in", "T in", "°C", "{:.1f}"), ("rh_in", "RH in", "%", "{:.0f}"),
    ("t_out", "T out", "°C", "{:.1f}"), ("rh_out", "RH out", "%", "{:.0f}"),
    ("i_glob", "I glob", "W/m²", "{:.0f}"), ("wind", "wind", "m/s", "{:.1f}"),
    ("rain", "rain", "", "{:.0f}"))


def _channel_value(ch: str, v: float | None, fmt: str) -> str:
    if v is None:
        return "—"
    if ch == "rain":
        return "wet" if v > 0 else "dry"
    return fmt.format(v)


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

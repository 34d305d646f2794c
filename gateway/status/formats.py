"""The status screen's small text formats: times, durations, sizes, numbers, sparklines, the
styled line every panel is made of, and ``fit``, which cuts a line to the columns there are
(``WIDTH`` for ``--once``, the terminal's on the screen) at a word, never inside a number.
"""

from __future__ import annotations

import math
import time

from rich.text import Text

from gateway.status import snapshot as S

WIDTH = 78
BARS = "▁▂▃▄▅▆▇█"
ALARM = "bold red"
WARN = "yellow"
OK = "green"
DIM = "dim"


def sparkline(series: S.Series | None, lo: float | None = None, hi: float | None = None) -> str:
    """Block characters, one per bin, scaled to [lo, hi] (the series' own range by default);
    a space where a bin has no data."""
    if series is None:
        return ""
    lo = series.lo if lo is None else lo
    hi = series.hi if hi is None else hi
    out = []
    for v in series.values:
        if not math.isfinite(v) or not math.isfinite(lo):
            out.append(" ")
            continue
        f = 0.5 if hi <= lo else min(max((v - lo) / (hi - lo), 0.0), 1.0)
        out.append(BARS[min(int(f * len(BARS)), len(BARS) - 1)])
    return "".join(out)


def stamp(t: float | None, seconds: bool = False) -> str:
    if t is None:
        return "—"
    return time.strftime("%Y-%m-%d %H:%M:%SZ" if seconds else "%Y-%m-%d %H:%MZ", time.gmtime(t))


def hhmm(t: float | None) -> str:
    return "—" if t is None else time.strftime("%H:%MZ", time.gmtime(t))


def duration(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "?"
    s = max(s, 0.0)
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 3 * 86400:
        return f"{int(s // 3600)} h {int(s % 3600 // 60)} min"
    return f"{s / 86400:.1f} days"


def size(n: int | None) -> str:
    if n is None:
        return "?"
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000  # type: ignore[assignment]
    return "?"


def tail(text: str, width: int) -> str:
    """A path cut on the left (its file name is what matters)."""
    return text if len(text) <= width else "…" + text[-(width - 1):]


def number(v: float | None, fmt: str = "{:.2f}") -> str:
    return "—" if v is None or not math.isfinite(v) else fmt.format(v)


def wrapped(text: str, indent: str, style: str = "", width: int = WIDTH) -> list[Text]:
    """``text`` over as many lines of ``width`` as it needs (a command must not be cut)."""
    out, row = [], indent
    for word in text.split():
        if len(row) + len(word) + 1 > width and row.strip():
            out.append(line((row.rstrip(), style)))
            row = indent + "  "
        row += word + " "
    out.append(line((row.rstrip(), style)))
    return out


def line(*parts: str | tuple[str, str]) -> Text:
    """One line of styled parts (a part: text, or (text, style)), never wrapped; ``fit`` cuts
    it to the width it is shown at."""
    t = Text(no_wrap=True, overflow="ellipsis")
    for p in parts:
        if isinstance(p, tuple):
            t.append(*p)
        else:
            t.append(p)
    return t


def fit(t: Text, width: int) -> Text:
    """``t`` cut to ``width`` columns with an ellipsis where it is longer: after its last whole
    " · " field when that keeps half the line, else after its last whole word (so a cut never
    shows half a number such as "13.0..13…"), else (one long word) at the width."""
    if t.cell_len <= width:
        return t
    plain, room = t.plain, width - 2  # room for " …"
    cut = plain.rfind(" · ", 0, room + 1)
    if cut < width // 2:
        cut = plain.rfind(" ", 0, room + 1)
    if cut <= 0 or not plain[:cut].strip():
        out = t[:max(width - 1, 0)]
        out.append("…")
    else:
        out = t[:cut]
        out.rstrip()
        out.append(" …")
    out.no_wrap, out.overflow = True, "ellipsis"
    return out


def fitted(lines: list[Text], width: int) -> list[Text]:
    return [fit(t, width) for t in lines]

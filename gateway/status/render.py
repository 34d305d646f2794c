"""A :class:`Snapshot` → lines of text, one list per panel: ``greenhouse_panel.py``,
``kits_panel.py``, ``gateway_panel.py``; here the title line, the choice of panel and ``--once``'s
plain text of them all.

Lines are rich ``Text`` (styles mark alarms and silences); ``plain()`` joins them without any
style for ``--once``. Every line is cut to the panel's ``width`` (``formats.fit``: at a word, never
inside a number): ``WIDTH``, 78 columns, for ``--once`` and an 80-column terminal; the screen
gives its own, so a wider terminal shows whole lines and a narrower one cuts them cleanly.
"""

from __future__ import annotations

from rich.text import Text

from gateway.status import snapshot as S
from gateway.status.formats import DIM, WIDTH, fit, stamp
from gateway.status.formats import line as _line
from gateway.status.gateway_panel import gateway_lines
from gateway.status.greenhouse_panel import greenhouse_lines
from gateway.status.kits_panel import kit_lines


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

"""What the status screen shows, as plain data: one :class:`Snapshot` of the farm at an instant.

A snapshot is built from the store (``store_source.py``) or from the gateway's messages over
Zenoh (``zenoh_source.py``); the renderers (``render.py`` and its panels) and the widgets
(``app.py``) only read it. All times are unix seconds on the gateway clock (a scaled clock in
tests and demos).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

SILENT_S = 300.0
"""A kit whose last record is older than this [s, gateway clock] is silent (as the gateway's
``device/<id>`` messages say, gateway/service/producers.py)."""
HEARTBEAT_STALE_S = 20.0
"""[wall s] A gateway status older than this (the service writes it every 5 s): not running."""
DAY = 86400.0
FINE_BINS = 144
"""The bins a source cuts the sparklines' span into (10 min of a day): the screen merges them
into as many columns as its width gives (:meth:`Series.rebinned`; 36 at 78 columns, 4 each)."""


@dataclass(frozen=True)
class Series:
    """24 h of one quantity in equal bins (oldest first, NaN where no data). ``lo``/``hi``: of the
    bins' means (the sparkline's scale); ``extent``: (min, max) of the points binned, NaN without
    any (the range shown beside the sparkline: ``value_range``)."""

    values: tuple[float, ...]
    start: float  # [unix s] start of the first bin
    end: float  # [unix s] end of the last bin
    extent: tuple[float, float] = (math.nan, math.nan)
    counts: tuple[int, ...] = ()  # points in each bin (empty: one in each bin with a value)

    def rebinned(self, n: int) -> Series:
        """The same span in ``n`` bins (no more than it has): each the mean of the points of
        the bins merged into it (bin ``j`` takes bins ``j·N//n`` to ``(j+1)·N//n − 1`` of N)."""
        size = len(self.values)
        if n >= size or n < 1:
            return self
        counts = self.counts or tuple(int(math.isfinite(v)) for v in self.values)
        values, merged = [], []
        for j in range(n):
            part = range(j * size // n, (j + 1) * size // n)
            k = sum(counts[i] for i in part)
            values.append(sum(self.values[i] * counts[i] for i in part if counts[i]) / k
                          if k else math.nan)
            merged.append(k)
        return Series(tuple(values), self.start, self.end, self.extent, tuple(merged))

    @property
    def finite(self) -> list[float]:
        return [v for v in self.values if math.isfinite(v)]

    @property
    def lo(self) -> float:
        return min(self.finite, default=math.nan)

    @property
    def hi(self) -> float:
        return max(self.finite, default=math.nan)


def span_of(first: float | None, end: float) -> float:
    """The sparklines' span: 24 h, or less while the data is younger (at least an hour), so a
    new kit's first hours fill the line instead of its last few characters."""
    if first is None:
        return DAY
    return min(max(end - first + 60.0, 3600.0), DAY)


def bin_series(points: Iterable[tuple[float, float | None]], end: float, bins: int = FINE_BINS,
               span: float = DAY) -> Series:
    """(t, value) points → the mean of each of ``bins`` equal bins over (end − span, end], and
    the points' own min and max there."""
    start = end - span
    width = span / bins
    sums, counts = [0.0] * bins, [0] * bins
    lo, hi = math.inf, -math.inf
    for t, v in points:
        if v is None or not math.isfinite(v) or not start < t <= end:
            continue
        i = min(int((t - start) / width), bins - 1)
        sums[i] += v
        counts[i] += 1
        lo, hi = min(lo, v), max(hi, v)
    extent = (lo, hi) if lo <= hi else (math.nan, math.nan)
    return Series(tuple(s / n if n else math.nan for s, n in zip(sums, counts, strict=True)),
                  start, end, extent, tuple(counts))


def value_range(series: Series | None, latest: float | None,
                at: float | None) -> tuple[float, float] | None:
    """The min..max shown beside a channel's sparkline: of every point of ``series`` (its minutes,
    not the bins' means, which smooth a gust below the reading it came from) and of the ``latest``
    reading shown beside it (taken at ``at``, unix s) when that lies in the series' window, so the
    latest shown is always inside the range, also before its minute is aggregated or when the
    minute's quality check dropped it. None: nothing to show."""
    lo, hi = series.extent if series is not None else (math.nan, math.nan)
    if (series is not None and latest is not None and math.isfinite(latest) and at is not None
            and series.start < at):
        lo = latest if math.isnan(lo) else min(lo, latest)
        hi = latest if math.isnan(hi) else max(hi, latest)
    return None if math.isnan(lo) else (lo, hi)


@dataclass(frozen=True)
class Reading:
    """The latest kit record of one side: channel → value (None: the sensor failed) and status."""

    t: float | None = None
    device_id: int | None = None
    values: dict[str, float | None] = field(default_factory=dict)
    status: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Skill:
    """Forecast error so far at one horizon, beside persistence on the same minutes."""

    horizon_min: int
    n: int
    mae: float  # [°C] mean |forecast − measured|
    persistence_mae: float  # [°C] mean |measured at issue − measured at validity|


@dataclass(frozen=True)
class Temperature:
    """Measured vs predicted inside temperature at the estimator's latest minute."""

    t: float | None = None  # the latest minute stepped
    measured: float | None = None
    predicted: float | None = None  # the one-step prediction made a minute before, for t
    forecasts: dict[int, float] = field(default_factory=dict)  # horizon [min] → T_in at t + h
    outlook: str = ""
    skill: tuple[Skill, ...] = ()
    measured_series: Series | None = None
    forecast_series: Series | None = None  # the 60-min forecasts placed at their validity time


@dataclass(frozen=True)
class Parameter:
    name: str
    value: float
    unit: str = ""
    lower: float | None = None
    upper: float | None = None

    @property
    def position(self) -> float | None:
        """0..1 inside the bounds (None when they are unknown)."""
        if self.lower is None or self.upper is None or not self.upper > self.lower:
            return None
        return (self.value - self.lower) / (self.upper - self.lower)


@dataclass(frozen=True)
class Ventilation:
    configured: bool  # a virtual sensor is set for the greenhouse (store: its config says)
    t: float | None = None
    flow: float | None = None  # [m3 s-1]
    heat_loss: float | None = None  # [W m-2]
    out_of_range: bool = False
    why_none: str = ""  # without a sensor set: why no shipped one fits the house ("" unknown)


@dataclass(frozen=True)
class Finding:
    id: str
    effect: str
    summary: str
    start: float | None
    first_seen: float
    last_seen: float
    revision: int


@dataclass(frozen=True)
class GreenhouseView:
    name: str
    farm: str = ""
    model: str = ""
    inside_device: int | None = None
    outside_device: int | None = None
    state: str = ""  # the estimator's state ("running", "waiting for data", …)
    inside: Reading = field(default_factory=Reading)
    outside: Reading = field(default_factory=Reading)
    series: dict[str, Series] = field(default_factory=dict)  # channel → 24 h
    temperature: Temperature = field(default_factory=Temperature)
    parameters: tuple[Parameter, ...] = ()
    ventilation: Ventilation = field(default_factory=lambda: Ventilation(False))
    findings: tuple[Finding, ...] = ()  # newest last


@dataclass(frozen=True)
class BoardCounters:
    """A kit's latest health packet: its own counters for its current boot (docs/wire-format.md,
    "Health packet"). Its drops are known at once; ``Kit.lost`` waits for the seq span."""

    dropped_full: int  # dropped from its ring: full
    dropped_old: int  # dropped from its ring: too old
    send_errors: int
    heap_free: int  # bytes
    uptime_s: int
    rssi_dbm: int | None
    reported: float | None  # when it arrived [gateway clock]

    @property
    def dropped(self) -> int:
        return self.dropped_full + self.dropped_old


@dataclass(frozen=True)
class Kit:
    device_id: int
    greenhouses: tuple[str, ...]  # "north in", "north out", … (empty: unassigned)
    last_seen: float | None  # time of its latest record [gateway clock]
    records: int
    boot: int | None  # the board's own boot counter
    stored_boot: int | None  # as stored: board counter + its key's boot base
    channels: dict[str, str] = field(default_factory=dict)  # channel → status name
    silent: bool = False
    refused: str = ""  # why its packets are refused as a whole, and the recovery
    lost: int = 0  # records the board lost before they were stored (all boots)
    board: BoardCounters | None = None  # its latest health packet


@dataclass(frozen=True)
class Link:
    """The gateway's Zenoh link as the gateway sees it (store) or as this screen sees it."""

    enabled: bool = True
    up: bool | None = None  # None: unknown
    summary: str = ""
    endpoints: tuple[str, ...] = ()
    waiting_keys: tuple[str, ...] = ()
    published: int | None = None


@dataclass(frozen=True)
class Outbox:
    pending: int | None = None
    max: int | None = None
    alarm_at: int | None = None
    alarm: bool = False
    oldest_t: float | None = None


@dataclass(frozen=True)
class Disk:
    store_bytes: int | None = None  # the SQLite file and its WAL
    free_bytes: int | None = None
    total_bytes: int | None = None
    path: str = ""


@dataclass(frozen=True)
class Diagnosis:
    """A greenhouse's last diagnosis run (``gateway_status`` row ``diagnosis``): ``words``, the
    run in words; ``warnings``, its warning-level notes (the figures are likely wrong) as
    (code, message). Its lesser notes stay in the row and the gateway's log."""

    words: str
    warnings: tuple[tuple[str, str], ...] = ()
    ok: bool = True  # False: the run failed (timed out, exited with an error)


def diagnosis_of(d: dict[str, Any]) -> Diagnosis:
    """A greenhouse's last run as the gateway keeps it (gateway/service/diagnosis.py
    ``DiagnosisRun.row``: the store's ``diagnosis`` status row, or a ``diagnosis`` message read
    back, gateway/status/messages.py) → its words and warnings, the same whichever source.
    A row left incomplete reads as far as it goes: a time that is no time (text, NaN, out of
    range) is "?", an outcome neither true nor false is "outcome unknown" (not a failure: nobody
    is called for it), notes not in a list are none."""
    when = d.get("when")
    stamp = "?"
    if isinstance(when, int | float) and not isinstance(when, bool):  # gmtime(None) is now
        try:
            stamp = time.strftime("%Y-%m-%d %H:%M", time.gmtime(when))
        except (ValueError, OverflowError, OSError):  # NaN, out of range
            pass
    ok = d.get("ok")
    outcome = "ok" if ok is True else "failed" if ok is False else "outcome unknown"
    note = f" ({d['note']})" if d.get("note") else ""
    n = d.get("findings")
    found = f", {n} finding{'s' * (n != 1)}" if isinstance(n, int) else ""
    notes = d.get("notes")
    warnings = tuple((str(x.get("code", "?")), str(x.get("message", "")))
                     for x in (notes if isinstance(notes, list) else ())
                     if isinstance(x, dict) and x.get("level") == "warning")
    return Diagnosis(f"last run {stamp} {outcome}{found}{note}", warnings, ok is not False)


@dataclass(frozen=True)
class Gateway:
    running: bool | None = None  # None: unknown (never seen)
    pid: int | None = None
    uptime_s: float | None = None  # [wall s]
    heartbeat_age_s: float | None = None  # [wall s]
    clock_scale: float = 1.0
    link: Link = field(default_factory=Link)
    outbox: Outbox = field(default_factory=Outbox)
    disk: Disk = field(default_factory=Disk)
    ingest: dict[str, int] = field(default_factory=dict)  # packet counters by outcome
    ingest_t: float | None = None  # when the gateway wrote them [unix s, gateway clock]
    diagnosis: dict[str, Diagnosis] = field(default_factory=dict)  # greenhouse → last run

    @property
    def rejects(self) -> dict[str, int]:
        """Rejected packets by reason (every counter but stored, duplicate, health (health
        packets taken) and lost_on_board, a count of records the boards lost, not of packets)."""
        return {k: v for k, v in self.ingest.items()
                if k not in ("stored", "duplicate", "health", "lost_on_board") and v}


@dataclass(frozen=True)
class Snapshot:
    source: str  # "store PATH" or "zenoh ENDPOINT"
    now: float | None  # gateway clock [unix s]; None when nothing is known yet
    wall: float  # wall time the snapshot was taken [unix s]
    farm: str = ""
    greenhouses: tuple[GreenhouseView, ...] = ()
    kits: tuple[Kit, ...] = ()
    gateway: Gateway = field(default_factory=Gateway)
    notes: tuple[str, ...] = ()  # what the source could not tell (said on the screen)


def skill_from_pairs(horizon_min: int, rows: Sequence[tuple[float, float, float]]) -> Skill:
    """(forecast, measured at issue, measured at validity) triples → :class:`Skill`."""
    n = len(rows)
    if not n:
        return Skill(horizon_min, 0, math.nan, math.nan)
    mae = sum(abs(f - m1) for f, _, m1 in rows) / n
    pers = sum(abs(m0 - m1) for _, m0, m1 in rows) / n
    return Skill(horizon_min, n, mae, pers)


def silent(last_seen: float | None, now: float | None) -> bool:
    return last_seen is None or (now is not None and now - last_seen > SILENT_S)


def attention(snap: Snapshot) -> list[str]:
    """What needs a person, one line each (``--once`` exits 1 when this is not empty)."""
    out = []
    gw = snap.gateway
    if gw.running is False:
        out.append("the gateway is not running" if gw.pid is not None or gw.heartbeat_age_s
                   is not None else "no gateway answers over Zenoh")
    if gw.link.enabled and gw.link.up is False:
        out.append("the Zenoh link is down")
    if gw.outbox.alarm:
        out.append(f"outbox alarm: {gw.outbox.pending} messages waiting")
    for k in snap.kits:
        if k.refused:
            out.append(f"kit {k.device_id} refused: {k.refused}")
        elif k.silent and k.greenhouses:
            out.append(f"kit {k.device_id} silent")
    for name, d in sorted(gw.diagnosis.items()):  # a wrong clock or site: figures likely wrong
        if not d.ok:
            out.append(f"diagnosis of {name} failed")
        if d.warnings:
            out.append(f"diagnosis of {name} warns: {', '.join(c for c, _ in d.warnings)}")
    return out

"""A :class:`Snapshot` from the gateway's own messages (the payloads of docs/cloud.md), as the
history queryable returns them: ``status``, ``device/<id>``, ``measurement/*``, ``forecast``,
``parameters``, ``ventilation``, ``finding``, ``diagnosis``. :class:`Messages` accumulates them (each once, by
idempotency key) and builds the snapshot; it knows nothing of Zenoh, so it is tested alone.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from gateway.publish import keyspace as K
from gateway.status import snapshot as S

SIDES = {
    "measurement/inside": {"temperature": ("t_in", 1.0), "relativeHumidity": ("rh_in", 100.0)},
    "measurement/outside": {"temperature": ("t_out", 1.0), "relativeHumidity": ("rh_out", 100.0),
                            "solarRadiation": ("i_glob", 1.0), "windSpeed": ("wind", 1.0),
                            "rainDetected": ("rain", 1.0)},
}
TIME_ATTRS = ("dateObserved", "dateIssued", "dateModified")


def message_key(key: str) -> tuple[str, str, str]:
    """A message or history-reply key → (farm, greenhouse, kind); ValueError otherwise."""
    parts = key.split("/")
    if len(parts) >= 5 and parts[3] == K.HISTORY:
        key = "/".join(parts[:3] + parts[4:])
    return K.split(key)


def _value(doc: dict[str, Any], attr: str, default: Any = None) -> Any:
    a = doc.get(attr)
    return a.get("value", default) if isinstance(a, dict) else default


def _time(v: Any) -> float | None:
    if isinstance(v, dict) and "@value" in v:
        v = v["@value"]
    if not isinstance(v, str):
        return None
    try:
        return datetime.fromisoformat(v.replace("Z", "+00:00")).timestamp()
    except ValueError:
        return None


def doc_time(doc: dict[str, Any]) -> float | None:
    for a in TIME_ATTRS:
        t = _time(_value(doc, a))
        if t is not None:
            return t
    return None


def _board(doc: dict[str, Any]) -> S.BoardCounters | None:
    """The board's own counters in a ``device/<id>`` message (payloads.device), if it has them."""
    c = _value(doc, "boardCounters")
    if not isinstance(c, dict):
        return None
    try:
        rssi = _value(doc, "rssi")
        return S.BoardCounters(int(c["droppedRingFull"]), int(c["droppedTooOld"]),
                               int(c["sendErrors"]), int(c["heapFree"]), int(c["uptime"]),
                               None if rssi is None else int(rssi),
                               _time(doc["boardCounters"].get("observedAt")))
    except (KeyError, TypeError, ValueError):
        return None  # a message from another version: shown without them


@dataclass
class _Forecast:
    measured: float | None
    horizons: dict[int, float]
    outlook: str


@dataclass
class Messages:
    bins: int = S.FINE_BINS
    seen: dict[str, float] = field(default_factory=dict)  # idempotency key → t
    latest: dict[tuple[str, str], tuple[float, dict[str, Any]]] = field(default_factory=dict)
    points: dict[tuple[str, str], dict[float, float]] = field(default_factory=dict)
    forecasts: dict[str, dict[float, _Forecast]] = field(default_factory=dict)
    finding_docs: dict[tuple[str, str], dict[str, Any]] = field(default_factory=dict)
    roles: dict[int, set[str]] = field(default_factory=dict)
    farm: str = ""
    newest: float | None = None  # gateway time of the newest message
    count: int = 0

    def add(self, key: str, payload: str | bytes) -> bool:
        """One message (a history reply or a live sample); False when not ours or a repeat."""
        try:
            farm, gh, kind = message_key(key)
            doc = json.loads(payload)
            idem = str(doc["idempotencyKey"]["value"])
        except (ValueError, KeyError, TypeError):
            return False
        if idem in self.seen:
            return False
        t = doc_time(doc)
        if t is None:
            return False
        self.seen[idem] = t
        self.count += 1
        self.farm = farm
        self.newest = t if self.newest is None else max(self.newest, t)
        old = self.latest.get((gh, kind))
        if old is None or t >= old[0]:
            self.latest[(gh, kind)] = (t, doc)
        if kind in SIDES:
            self._measurement(gh, kind, t, doc)
        elif kind == "forecast":
            self._forecast(gh, t, doc)
        elif kind == "finding":
            fid = str(doc.get("id", "")).rsplit(":", 1)[-1]
            prev = self.finding_docs.get((gh, fid))
            if prev is None or (_value(doc, "revision", 0) >= _value(prev, "revision", 0)):
                self.finding_docs[(gh, fid)] = doc
        return True

    def _measurement(self, gh: str, kind: str, t: float, doc: dict[str, Any]) -> None:
        for attr, (ch, factor) in SIDES[kind].items():
            v = _value(doc, attr)
            if isinstance(v, bool | int | float):
                self.points.setdefault((gh, ch), {})[t] = float(v) * factor
        dev = _device_of(doc)
        if dev is not None:
            self.roles.setdefault(dev, set()).add(f"{gh} {'in' if kind.endswith('inside') else 'out'}")

    def _forecast(self, gh: str, t: float, doc: dict[str, Any]) -> None:
        hs = {}
        for f in doc.get("airTemperatureForecast", []):
            h, v = _value(f, "horizon"), f.get("value")
            if isinstance(h, int) and isinstance(v, int | float):
                hs[h] = float(v)
        self.forecasts.setdefault(gh, {})[t] = _Forecast(
            _value(doc, "temperature"), hs, str(_value(doc, "outlook", "")))

    def trim(self, keep_s: float = S.DAY + 7200) -> None:
        """Forget series points and repeat guards older than ``keep_s`` before the newest."""
        if self.newest is None:
            return
        cut = self.newest - keep_s
        self.seen = {k: t for k, t in self.seen.items() if t >= cut}
        for pts in self.points.values():
            for t in [t for t in pts if t < cut]:
                del pts[t]
        for fc in self.forecasts.values():
            for t in [t for t in fc if t < cut]:
                del fc[t]

    # -- the snapshot ---------------------------------------------------------------------------
    def snapshot(self, source: str, wall: float, answered: bool | None, link: S.Link,
                 notes: tuple[str, ...] = ()) -> S.Snapshot:
        now = self.newest
        ghs = sorted({gh for gh, kind in self.latest if gh != K.UNASSIGNED and kind == "status"} |
                     {gh for gh, kind in self.latest if kind in SIDES})
        views = [self._greenhouse(gh, now) for gh in ghs]
        kits = self._kits(now)
        status = [doc for (gh, kind), (_, doc) in self.latest.items() if kind == "status"]
        gw = self._gateway(status, answered, link)
        more = list(notes) + _store_failure(status)
        if not self.count:
            more.append("no message from a gateway yet")
        return S.Snapshot(source, now, wall, self.farm, tuple(views), tuple(kits), gw, tuple(more))

    def _reading(self, gh: str, kind: str) -> S.Reading:
        got = self.latest.get((gh, kind))
        if got is None:
            return S.Reading()
        t, doc = got
        vals: dict[str, float | None] = {}
        st: dict[str, str] = {}
        for attr, (ch, factor) in SIDES[kind].items():
            v = _value(doc, attr)
            vals[ch] = float(v) * factor if isinstance(v, bool | int | float) else None
            sub = doc.get(attr, {})
            st[ch] = str(_value(sub, "sensorStatus", "ok")) if isinstance(sub, dict) else "ok"
        for ch, why in (_value(doc, "missingChannels") or {}).items():
            st[ch] = str(why)
        return S.Reading(t, _device_of(doc), vals, st)

    def _greenhouse(self, gh: str, now: float | None) -> S.GreenhouseView:
        end = now if now is not None else 0.0
        span = S.span_of(min((t for (g, _), pts in self.points.items() if g == gh for t in pts
                              if t > end - S.DAY), default=None), end)
        series = {ch: S.bin_series(pts.items(), end, self.bins, span)
                  for (g, ch), pts in self.points.items() if g == gh}
        status = self.latest.get((gh, "status"), (0.0, {}))[1]
        inside, outside = self._reading(gh, "measurement/inside"), self._reading(gh, "measurement/outside")
        params = self.latest.get((gh, "parameters"))
        vent = self.latest.get((gh, "ventilation"))
        model = str(_value(params[1], "model", "")) if params else ""
        return S.GreenhouseView(
            name=gh, farm=self.farm, model=model, inside_device=inside.device_id,
            outside_device=outside.device_id, state=str(_value(status, "estimatorState", "")),
            inside=inside, outside=outside, series=series,
            temperature=self._temperature(gh, end, span),
            parameters=_parameters(params[1]) if params else (),
            ventilation=_ventilation(*vent) if vent else S.Ventilation(False),
            findings=tuple(sorted((_finding(d) for (g, _), d in self.finding_docs.items() if g == gh),
                                  key=lambda f: f.last_seen)))

    def _temperature(self, gh: str, end: float, span: float) -> S.Temperature:
        fcs = self.forecasts.get(gh, {})
        if not fcs:
            return S.Temperature()
        t = max(fcs)
        last = fcs[t]
        skill = []
        for h in sorted(last.horizons):
            rows = [(f.horizons[h], f.measured, fcs[ti + 60 * h].measured) for ti, f in fcs.items()
                    if h in f.horizons and f.measured is not None and end - S.DAY <= ti
                    and ti + 60 * h in fcs and fcs[ti + 60 * h].measured is not None]
            skill.append(S.skill_from_pairs(h, rows))  # type: ignore[arg-type]
        h_max = max(last.horizons, default=60)
        measured = [(ti + 30.0, f.measured) for ti, f in fcs.items()]
        ahead = [(ti + 60 * h_max + 30.0, f.horizons.get(h_max)) for ti, f in fcs.items()]
        return S.Temperature(t, last.measured, None, dict(last.horizons), last.outlook, tuple(skill),
                             S.bin_series(measured, end, self.bins, span),
                             S.bin_series(ahead, end, self.bins, span))

    def _kits(self, now: float | None) -> list[S.Kit]:
        newest: dict[int, tuple[float, dict[str, Any]]] = {}
        for (_, kind), (t, doc) in self.latest.items():
            if kind.startswith("device/") and kind[7:].isdigit():
                dev = int(kind[7:])
                if dev not in newest or t > newest[dev][0]:
                    newest[dev] = (t, doc)
        out = []
        for dev in sorted(set(newest) | set(self.roles)):
            doc = newest.get(dev, (0.0, {}))[1]
            last = _time(_value(doc, "dateLastValueReported"))
            for (_, kind), (t, m) in self.latest.items():  # a newer record than the snapshot
                if kind in SIDES and _device_of(m) == dev and (last is None or t > last):
                    last = t
            chans = _value(doc, "channelStatus") or {}
            chans = {} if "all" in chans else {str(k): str(v) for k, v in chans.items()}
            board = _value(doc, "boardBootCounter", _value(doc, "bootCounter"))
            out.append(S.Kit(dev, _roles(self.roles.get(dev, set())), last,
                             int(_value(doc, "records", 0) or 0), board, _value(doc, "bootCounter"),
                             chans, S.silent(last, now),
                             lost=int(_value(doc, "recordsLost", 0) or 0), board=_board(doc)))
        return out

    def _gateway(self, status: list[dict[str, Any]], answered: bool | None, link: S.Link) -> S.Gateway:
        doc = max(status, key=lambda d: doc_time(d) or 0.0) if status else {}
        pending = _value(doc, "outboxPending")
        ingest = _value(doc, "ingestCounters") or {}
        peers, routers = _value(doc, "zenohPeers"), _value(doc, "zenohRouters")
        when = doc_time(doc) if doc else None
        if peers is not None:
            seen = f"the gateway's own link at {_hhmm(when)}: {peers} peers, {routers} routers"
            link = S.Link(link.enabled, link.up, f"{link.summary}; {seen}", link.endpoints)
        return S.Gateway(
            running=answered, uptime_s=_value(doc, "gatewayUptime"), link=link,
            outbox=S.Outbox(pending, alarm=bool(_value(doc, "outboxAlarm", False))),
            disk=S.Disk(_value(doc, "storeSize"), _value(doc, "diskFree"), _value(doc, "diskTotal"),
                        f"(as of {_hhmm(when)}, gateway clock)" if doc else ""),
            ingest={str(k): int(v) for k, v in ingest.items()}, ingest_t=when if ingest else None,
            diagnosis=self._diagnosis())

    def _diagnosis(self) -> dict[str, S.Diagnosis]:
        """Each greenhouse's newest ``diagnosis`` message as the run it tells of (the store's
        status row read the same way: ``S.diagnosis_of``), unless the greenhouse's newest
        ``status`` says the gateway's diagnosis is switched off: its last run stays in the
        history, and its failure or warnings would ask for attention for ever."""
        out = {}
        for (gh, kind), (t, doc) in self.latest.items():
            status = self.latest.get((gh, "status"), (0.0, {}))[1]
            if kind == "diagnosis" and _value(status, "diagnosisEnabled") is not False:
                out[gh] = S.diagnosis_of(_run_row(t, doc))
        return out


def _store_failure(status: list[dict[str, Any]]) -> list[str]:
    """The note of the store's latest failure to be written, as the newest ``status`` that
    tells of one says it (``storeLastFailure``, times in UTC)."""
    told = [d for d in status if isinstance(_value(d, "storeLastFailure"), dict)]
    if not told:
        return []
    f = _value(max(told, key=lambda d: doc_time(d) or 0.0), "storeLastFailure")
    return [f"store unwritable {f.get('since')}–{f.get('until')}: {f.get('cause')}; nothing "
            "acknowledged was lost (the kits held their records)"]


def _roles(roles: set[str]) -> tuple[str, ...]:
    """{"north in", "north out"} → ("north in+out",)."""
    ghs = sorted({r.rsplit(" ", 1)[0] for r in roles})
    return tuple(f"{g} in+out" if {f"{g} in", f"{g} out"} <= roles else
                 next(r for r in sorted(roles) if r.startswith(g + " ")) for g in ghs)


def _device_of(doc: dict[str, Any]) -> int | None:
    rec = _value(doc, "kitRecord")
    if isinstance(rec, dict) and isinstance(rec.get("device"), int):
        return rec["device"]
    return None


def _parameters(doc: dict[str, Any]) -> tuple[S.Parameter, ...]:
    out = []
    for name in _value(doc, "parameterNames", []) or []:
        a = doc.get(name)
        if not isinstance(a, dict) or not isinstance(a.get("value"), int | float):
            continue
        lo, hi = _value(a, "lowerBound"), _value(a, "upperBound")
        out.append(S.Parameter(name, float(a["value"]), str(a.get("unitCode", "")),
                               float(lo) if isinstance(lo, int | float) else None,
                               float(hi) if isinstance(hi, int | float) else None))
    return tuple(out)


def _ventilation(t: float, doc: dict[str, Any]) -> S.Ventilation:
    return S.Ventilation(True, t, _value(doc, "ventilationFlow"), _value(doc, "ventilationHeatLoss"),
                         bool(_value(doc, "outOfTrainingRange", False)))


def _run_row(t: float, doc: dict[str, Any]) -> dict[str, Any]:
    """A ``diagnosis`` message (payloads.diagnosis_run) → the run's row as the gateway keeps it
    (gateway/service/diagnosis.py ``DiagnosisRun.row``)."""
    return {"when": t, "ok": _value(doc, "succeeded"), "note": _value(doc, "summary", ""),
            "findings": _value(doc, "findingCount"), "notes": _value(doc, "runNotes")}


def _finding(doc: dict[str, Any]) -> S.Finding:
    first = _time(_value(doc, "dateDetected")) or math.nan
    return S.Finding(str(doc.get("id", "")).rsplit(":", 1)[-1], str(_value(doc, "effect", "?")),
                     str(_value(doc, "summary", "")), _time(_value(doc, "startTime")), first,
                     _time(_value(doc, "dateModified")) or first, int(_value(doc, "revision", 1)))


def _hhmm(t: float | None) -> str:
    import time

    return "?" if t is None else time.strftime("%H:%MZ", time.gmtime(t))

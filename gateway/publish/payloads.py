"""JSON payloads: NGSI-LD normalized entities shaped after the FIWARE Smart Data Models.

Inside and outside climate are two ``WeatherObserved`` entities, linked from the greenhouse's
``AgriGreenhouse`` (``hasWeatherObserved``, one instance per side told apart by ``datasetId``);
kit health is a ``Device``. Our own quantities (forecast, parameters, fluxes, ventilation,
findings, the diagnosis's last run) are entities of our own types in the same shape
(docs/cloud.md lists every attribute). Units are UN/CEFACT common codes (``unitCode``); a unit
that has none travels as a ``unitText`` sub-property. Times are ISO 8601 UTC; relative humidity
is a fraction 0–1 as the models define it. Every payload carries ``idempotencyKey``: the cloud
drops repeats by it.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

CORE_CONTEXT = "https://uri.etsi.org/ngsi-ld/v1/ngsi-ld-core-context-v1.8.jsonld"
CONTEXTS = {
    "WeatherObserved": "https://raw.githubusercontent.com/smart-data-models/dataModel.Weather/master/context.jsonld",
    "AgriGreenhouse": "https://raw.githubusercontent.com/smart-data-models/dataModel.Agrifood/master/context.jsonld",
    "Device": "https://raw.githubusercontent.com/smart-data-models/dataModel.Device/master/context.jsonld",
}

UNIT_CODES = {
    "degC": "CEL", "°C": "CEL", "K": "KEL", "1": "C62", "-": "C62", "%": "P1",
    "W m-2": "D54", "W m-2 K-1": "D55", "m s-1": "MTS", "m3 s-1": "MQS", "kPa": "KPA",
    "s": "SEC", "min": "MIN",
}
"""UN/CEFACT Recommendation 20 common codes of the units we publish."""

CHANNEL_STATUS = {0x00: "ok", 0x01: "partial", 0x10: "no_sensor", 0x11: "timeout",
                  0x12: "checksum", 0x13: "range", 0x14: "saturated", 0x15: "not_ready"}


def iso(t: float) -> str:
    """Unix seconds → ``2009-11-01T00:00:00Z``, with milliseconds (truncated, so an instant
    never moves into the next second or minute) when ``t`` is not whole."""
    ms = math.floor(t * 1000.0 + 1e-6)
    whole, frac = divmod(ms, 1000)
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(whole))
    return f"{stamp}Z" if frac == 0 else f"{stamp}.{frac:03d}Z"


def date_time(t: float) -> dict:
    return {"type": "Property", "value": {"@type": "DateTime", "@value": iso(t)}}


def prop(value: Any, unit: str | None = None, observed: float | None = None,
         dataset: str | None = None, **sub: Any) -> dict:
    """A Property; ``unit`` becomes ``unitCode`` (or a ``unitText`` sub-property when it has
    no code); ``dataset`` its ``datasetId`` (one of several instances); ``sub`` are
    sub-properties (plain values become Properties)."""
    out: dict[str, Any] = {"type": "Property", "value": value}
    if dataset is not None:
        out["datasetId"] = dataset
    if unit:
        code = UNIT_CODES.get(unit)
        if code:
            out["unitCode"] = code
        else:
            out["unitText"] = {"type": "Property", "value": unit}
    if observed is not None:
        out["observedAt"] = iso(observed)
    for k, v in sub.items():
        out[k] = v if isinstance(v, dict) and "type" in v else {"type": "Property", "value": v}
    return out


def rel(obj: str, **extra: Any) -> dict:
    return {"type": "Relationship", "object": obj, **extra}


def point(latitude: float, longitude: float) -> dict:
    return {"type": "GeoProperty", "value": {"type": "Point", "coordinates": [longitude, latitude]}}


@dataclass(frozen=True)
class Place:
    """Who and where: the farm, the greenhouse and its coordinates."""

    farm: str
    greenhouse: str
    latitude: float
    longitude: float

    def urn(self, kind: str, *more: str) -> str:
        return ":".join(["urn:ngsi-ld", kind, "serra", self.farm, self.greenhouse, *more])

    @property
    def agri_greenhouse(self) -> str:
        return self.urn("AgriGreenhouse")

    def weather(self, side: str) -> str:
        return self.urn("WeatherObserved", side)


def device_urn(farm: str, device_id: int) -> str:
    return f"urn:ngsi-ld:Device:serra:{farm}:{device_id}"


def entity(kind: str, urn: str, idem: str, attrs: Mapping[str, Any]) -> dict:
    ctx = [CONTEXTS[kind], CORE_CONTEXT] if kind in CONTEXTS else [CORE_CONTEXT]
    return {"id": urn, "type": kind, **attrs, "idempotencyKey": prop(idem), "@context": ctx}


def dumps(payload: Mapping[str, Any]) -> str:
    """Compact JSON; NaN or infinity is a bug (NGSI-LD has no such values) and raises."""
    return json.dumps(payload, separators=(",", ":"), allow_nan=False, ensure_ascii=False)


# -- the kinds -------------------------------------------------------------------------------
SIDES = {
    "inside": (("t_in", "temperature", "degC", 1.0), ("rh_in", "relativeHumidity", "1", 0.01)),
    "outside": (("t_out", "temperature", "degC", 1.0), ("rh_out", "relativeHumidity", "1", 0.01),
                ("i_glob", "solarRadiation", "W m-2", 1.0), ("wind", "windSpeed", "m s-1", 1.0)),
}
"""Kit channel → WeatherObserved attribute, unit and factor (RH: % → fraction 0–1)."""


@dataclass(frozen=True)
class Reading:
    """One kit record as the store holds it: channel → (value or None, status code)."""

    device_id: int
    boot: int
    seq: int
    t: float
    channels: Mapping[str, tuple[float | None, int]]


def weather_observed(place: Place, side: str, r: Reading, idem: str) -> dict:
    """``measurement/inside`` or ``measurement/outside``: one kit record, one side."""
    attrs: dict[str, Any] = {
        "dateObserved": date_time(r.t),
        "location": point(place.latitude, place.longitude),
        "name": prop(f"{place.greenhouse} {side}"),
        "refDevice": rel(device_urn(place.farm, r.device_id)),
        "kitRecord": prop({"device": r.device_id, "boot": r.boot, "seq": r.seq}),
    }
    for channel, name, unit, factor in SIDES[side]:
        value, status = r.channels[channel]
        if value is None:
            continue  # never a made-up number: a failed read is absent
        sub = {} if status == 0 else {"sensorStatus": CHANNEL_STATUS.get(status, str(status))}
        v = value * factor
        if name == "relativeHumidity":
            v = min(max(v, 0.0), 1.0)
        attrs[name] = prop(round(v, 6), unit, r.t, **sub)
    if side == "outside" and r.channels["rain"][0] is not None:
        attrs["rainDetected"] = prop(bool(r.channels["rain"][0]), None, r.t)
    missing = [ch for ch, *_ in SIDES[side] if r.channels[ch][0] is None]
    if missing:
        attrs["missingChannels"] = prop({ch: CHANNEL_STATUS.get(r.channels[ch][1], "?") for ch in missing})
    return entity("WeatherObserved", place.weather(side), idem, attrs)


def agri_greenhouse(place: Place, t: float, devices: Iterable[int], idem: str,
                    rh_in: float | None = None, t_in: float | None = None,
                    state: Mapping[str, Any] | None = None) -> dict:
    """``status``: the greenhouse, its two WeatherObserved and its kits, and the service state."""
    attrs: dict[str, Any] = {
        "dateModified": date_time(t),
        "name": prop(place.greenhouse),
        "location": point(place.latitude, place.longitude),
        "hasAgriParcelParent": rel(f"urn:ngsi-ld:AgriParcel:serra:{place.farm}"),
        "hasWeatherObserved": [
            rel(place.weather(side), datasetId=f"urn:ngsi-ld:Dataset:serra:{side}")
            for side in ("inside", "outside")],
        "hasDevice": {"type": "ListRelationship",
                      "objectList": [{"object": device_urn(place.farm, d)} for d in sorted(set(devices))]},
    }
    if rh_in is not None:
        attrs["relativeHumidity"] = prop(round(min(max(rh_in / 100.0, 0.0), 1.0), 6), "1", t)
    if t_in is not None:
        attrs["temperature"] = prop(round(t_in, 4), "degC", t)
    for k, v in (state or {}).items():
        attrs[k] = prop(v, None, t)
    return entity("AgriGreenhouse", place.agri_greenhouse, idem, attrs)


CONTROLLED = ("temperature", "humidity", "solarRadiation", "windSpeed", "precipitation")
"""What a Serra kit measures, in the Device model's controlledProperty vocabulary (its rain
detector is reported as precipitation)."""


_BOARD_COUNTERS = (("bootCounter", "board_boot"), ("uptime", "uptime_s"), ("records", "records"),
                   ("droppedRingFull", "dropped_full"), ("droppedTooOld", "dropped_old"),
                   ("sent", "sent"), ("acked", "acked"), ("rejected", "rejected"),
                   ("sendErrors", "send_errors"), ("heapFree", "heap_free"), ("ring", "ring"))
"""``boardCounters``' names and the health packet's fields (uptime in s, heapFree in bytes)."""


def device(farm: str, device_id: int, t: float, idem: str, *, state: str, boot: int | None,
           records: int, last_seen: float | None, channels: Mapping[str, str],
           greenhouses: Sequence[Place], board_boot: int | None = None,
           lost: int = 0, board: Mapping[str, Any] | None = None) -> dict:
    """``device/<id>``: a kit's health (``deviceState`` ok | silent | unassigned).

    ``recordsLost``: records the board made but lost before the gateway stored them (its ring
    overflowed, or it restarted), all boots, counted once they can no longer arrive.

    ``board``: the fields of its latest health packet (gateway/store/board_health.BoardReport),
    observed when it arrived: ``recordsDroppedOnBoard`` (its ring's drops this boot, as the
    board counts them: known at once, where ``recordsLost`` waits for the seq span),
    ``boardCounters`` (the rest) and ``rssi`` [dBm] when the board knows it.

    ``bootCounter`` is the boot as stored (unique per device, as in ``kitRecord``);
    ``boardBootCounter`` the board's own counter (they differ after a key rotation)."""
    attrs: dict[str, Any] = {
        "category": prop(["sensor"]),
        "controlledProperty": prop(list(CONTROLLED)),
        "serialNumber": prop(str(device_id)),
        "deviceState": prop(state, None, t),
        "dateObserved": date_time(t),
        "records": prop(records, None, t),
        "recordsLost": prop(lost, None, t),
        "channelStatus": prop(dict(channels) or {"all": "no record yet"}, None, t),
    }
    if boot is not None:
        attrs["bootCounter"] = prop(boot, None, t)
    if board_boot is not None:
        attrs["boardBootCounter"] = prop(board_boot, None, t)
    if last_seen is not None:
        attrs["dateLastValueReported"] = date_time(last_seen)
    if board is not None:
        tb = board["t_recv"]
        attrs["recordsDroppedOnBoard"] = prop(board["dropped_full"] + board["dropped_old"], None, tb)
        attrs["boardCounters"] = prop({name: board[key] for name, key in _BOARD_COUNTERS}, None, tb)
        if board["rssi_dbm"] is not None:
            attrs["rssi"] = prop(board["rssi_dbm"], "dBm", tb)
    if greenhouses:
        attrs["location"] = point(greenhouses[0].latitude, greenhouses[0].longitude)
        attrs["controlledAsset"] = {"type": "ListRelationship",
                                    "objectList": [{"object": p.agri_greenhouse} for p in greenhouses]}
    return entity("Device", device_urn(farm, device_id), idem, attrs)


def forecast(place: Place, t: float, idem: str, *, model: str, outlook: str, t_in: float,
             horizons: Sequence[tuple[int, float]]) -> dict:
    """``forecast``: inside air temperature at t + h for each horizon h [min], made at t."""
    return entity("GreenhouseForecast", place.urn("GreenhouseForecast"), idem, {
        "refAgriGreenhouse": rel(place.agri_greenhouse),
        "dateIssued": date_time(t),
        "outlook": prop(outlook),
        "model": prop(model),
        "temperature": prop(round(t_in, 4), "degC", t),
        "airTemperatureForecast": [
            prop(round(v, 4), "degC", t, f"urn:ngsi-ld:Dataset:serra:horizon:PT{h}M",
                 horizon=prop(h, "min"), validAt=date_time(t + 60 * h))
            for h, v in horizons],
    })


@dataclass(frozen=True)
class ParameterValue:
    name: str
    value: float
    unit: str
    lower: float
    upper: float


def parameters(place: Place, t: float, idem: str, *, model: str,
               values: Sequence[ParameterValue]) -> dict:
    """``parameters``: the online estimator's parameters in force at t, with their hard box."""
    attrs: dict[str, Any] = {
        "refAgriGreenhouse": rel(place.agri_greenhouse),
        "dateObserved": date_time(t),
        "model": prop(model),
        "parameterNames": prop([p.name for p in values]),
    }
    for p in values:
        attrs[p.name] = prop(_num(p.value), p.unit, t, lowerBound=_num(p.lower),
                             upperBound=_num(p.upper))
    return entity("GreenhouseModelParameters", place.urn("GreenhouseModelParameters"), idem, attrs)


def fluxes(place: Place, t: float, idem: str, *, model: str, values: Mapping[str, float]) -> dict:
    """``fluxes``: each heat-flux term of the model at t [W m-2 of floor]."""
    attrs: dict[str, Any] = {
        "refAgriGreenhouse": rel(place.agri_greenhouse),
        "dateObserved": date_time(t),
        "model": prop(model),
        "fluxNames": prop(list(values)),
    }
    for name, v in values.items():
        attrs[name] = prop(_num(v), "W m-2", t)
    return entity("GreenhouseHeatFluxes", place.urn("GreenhouseHeatFluxes"), idem, attrs)


def ventilation(place: Place, t: float, idem: str, *, flow: float, heat_loss: float,
                out_of_range: bool = False) -> dict:
    """``ventilation``: the virtual ventilation sensor's flow [m3 s-1] and heat loss [W m-2]."""
    return entity("GreenhouseVentilation", place.urn("GreenhouseVentilation"), idem, {
        "refAgriGreenhouse": rel(place.agri_greenhouse),
        "dateObserved": date_time(t),
        "ventilationFlow": prop(max(0.0, _num(flow)), "m3 s-1", t),
        "ventilationHeatLoss": prop(_num(heat_loss), "W m-2", t),
        "outOfTrainingRange": prop(bool(out_of_range), None, t),
    })


def finding(place: Place, idem: str, *, finding_id: str, effect: str, start: float | None,
            first_seen: float, last_seen: float, revision: int, detail: Mapping[str, Any]) -> dict:
    """``finding``: an effect the diagnosis traced in the residual (docs/effects.md)."""
    params = dict(detail.get("params", {}))
    unit = str(params.pop("unit", ""))
    amp = next((float(v) for v in params.values() if isinstance(v, int | float)), 0.0)
    attrs: dict[str, Any] = {
        "refAgriGreenhouse": rel(place.agri_greenhouse),
        "effect": prop(effect),
        "revision": prop(revision),
        "dateDetected": date_time(first_seen),
        "dateModified": date_time(last_seen),
        "summary": prop(str(detail.get("summary") or effect)),
        "amplitude": prop(_num(amp), unit or None),
    }
    if start is not None:
        attrs["startTime"] = date_time(start)
    if detail.get("evidence"):
        attrs["evidence"] = prop(str(detail["evidence"]))
    return entity("GreenhouseFinding", place.urn("GreenhouseFinding", finding_id), idem, attrs)


def diagnosis_run(place: Place, idem: str, *, when: float, ok: bool, note: str, findings: int,
                  notes: Sequence[Mapping[str, Any]]) -> dict:
    """``diagnosis``: a greenhouse's last daily diagnosis run (gateway/service/diagnosis.py
    ``DiagnosisRun``), one entity per greenhouse, sent again after every run. ``dateObserved``:
    when it ran [gateway clock]; ``succeeded`` false: it failed (timed out, exited with an error,
    output unreadable), a run skipped for too little data succeeded and its ``summary`` says so;
    ``findingCount``: the findings it traced (each also a ``finding`` message when new or
    changed); ``runNotes``: what it said of the data beside them, ``{code, level, message}``
    records, ``level`` ``warning`` (the figures are likely wrong) or ``note``."""
    kept = [{"code": str(n.get("code") or "?"),
             "level": "warning" if n.get("level") == "warning" else "note",
             "message": str(n.get("message") or "")} for n in notes]
    return entity("GreenhouseDiagnosisRun", place.urn("GreenhouseDiagnosisRun"), idem, {
        "refAgriGreenhouse": rel(place.agri_greenhouse),
        "dateObserved": date_time(when),
        "succeeded": prop(bool(ok)),
        "summary": prop(note or ("diagnosis ran" if ok else "diagnosis failed")),
        "findingCount": prop(int(findings)),
        "runNotes": prop(kept),
    })


def _num(v: float) -> float:
    v = float(v)
    if not math.isfinite(v):
        raise ValueError(f"not a finite number: {v}")
    return v

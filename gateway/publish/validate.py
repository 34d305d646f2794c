"""Offline validation of every payload kind against the shipped schemas (schemas/*/README.md).

Each payload is an NGSI-LD normalized entity. It is checked against our NGSI-LD shape schema,
then (FIWARE types) its key-values projection against the published Smart Data Models schema of
its type, or (our own types) against ``schemas/serra/entities.schema.json``. Nothing is ever
fetched: the registry holds the shipped files and its ``retrieve`` raises, except for the three
URIs an upstream defect of ``device-schema.json`` points outside itself (README there).
Date-time formats are checked (``jsonschema[format-nongpl]``).
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from functools import cache
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator
from referencing import Registry, Resource
from referencing.exceptions import NoSuchResource
from referencing.jsonschema import DRAFT202012

SCHEMAS = Path(__file__).parent / "schemas"
SDM = "https://smart-data-models.github.io/"
FIWARE_TYPES = {
    "WeatherObserved": SDM + "dataModel.Weather/WeatherObserved/schema.json",
    "AgriGreenhouse": SDM + "dataModel.Agrifood/AgriGreenhouse/schema.json",
    "Device": SDM + "dataModel.Device/Device/schema.json",
}
OWN_TYPES = ("GreenhouseForecast", "GreenhouseModelParameters", "GreenhouseHeatFluxes",
             "GreenhouseVentilation", "GreenhouseFinding", "GreenhouseDiagnosisRun")
NGSI_LD = "https://serra.invalid/schemas/ngsi-ld-entity.schema.json"
ENTITIES = "https://serra.invalid/schemas/entities.schema.json"
_DEVICE_ALIAS = SDM + "dataModel.Device/device-schema.json"
_DEVICE_ID = SDM + "data-models/specs/Device/device-schema.json"
_DEVICE_DEFS = ("CategoryType", "ControlledPropertyType", "SupportedProtocolType")


class PayloadError(ValueError):
    """A payload that does not follow its schemas; the message lists every error with its path."""


@cache
def registry() -> Registry:
    docs = {}
    for path in sorted(SCHEMAS.glob("*/*.json")):
        doc = json.loads(path.read_text(encoding="utf-8"))
        docs[doc["$id"]] = doc
    docs[_DEVICE_ALIAS] = docs[_DEVICE_ID]  # upstream defect 1 (schemas/fiware/README.md)
    device_defs = docs[_DEVICE_ID]["definitions"]

    def retrieve(uri: str) -> Resource:
        name = uri.removeprefix(SDM + "definitions/")  # upstream defect 2: exactly three URIs
        if name in _DEVICE_DEFS:
            return DRAFT202012.create_resource(device_defs[name])
        # referencing's _attrs.pyi hides its attrs classes' fields from mypy (an old
        # __dataclass_transform__ name): the field-wise __init__ is real
        raise NoSuchResource(ref=uri)  # type: ignore[call-arg]  # never the network

    # Several files say "$schema": "http://json-schema.org/schema#" (no draft): read as 2020-12.
    return Registry(retrieve=retrieve).with_resources(  # type: ignore[call-arg]  # as above
        (uri, DRAFT202012.create_resource(doc)) for uri, doc in docs.items())


@cache
def _validator(uri: str) -> Draft202012Validator:
    """A validator of the schema at ``uri`` (resolved through the offline registry)."""
    return Draft202012Validator({"$ref": uri}, registry=registry(),
                                format_checker=Draft202012Validator.FORMAT_CHECKER)


def _plain(attr: Mapping[str, Any]) -> Any:
    """An attribute instance's key-values value."""
    if attr.get("type") == "Relationship":
        return attr["object"]
    if attr.get("type") == "ListRelationship":
        return [o["object"] for o in attr["objectList"]]
    v = attr.get("value")
    if isinstance(v, dict) and v.get("@type") == "DateTime":
        return v["@value"]
    return v


def projections(entity: Mapping[str, Any]) -> Iterator[dict[str, Any]]:
    """The key-values form of a normalized entity: one per instance of its multi-instance
    attributes (attributes with several ``datasetId`` instances are taken in turn)."""
    multi = {k: v for k, v in entity.items() if isinstance(v, list) and k != "@context"}
    rounds = max((len(v) for v in multi.values()), default=1)
    for i in range(rounds):
        out: dict[str, Any] = {}
        for k, v in entity.items():
            if k in ("id", "type", "@context"):
                out[k] = v
            elif k in multi:
                out[k] = _plain(v[min(i, len(v) - 1)])
            else:
                out[k] = _plain(v)
        yield out


def errors(payload: Mapping[str, Any]) -> list[str]:
    """Every schema error of ``payload`` as ``schema: path: message`` lines (empty when valid)."""
    out = [f"ngsi-ld: {_where(e)}: {e.message}" for e in _validator(NGSI_LD).iter_errors(payload)]
    kind = payload.get("type")
    if kind in FIWARE_TYPES:
        v = _validator(FIWARE_TYPES[kind])
        for kv in projections(payload):
            out += [f"{kind} (key-values): {_where(e)}: {e.message}" for e in v.iter_errors(kv)]
            if kind == "Device":  # upstream defect 3: Device-Commons' own checks, applied here
                for name, ref in (("category", "CategoryType"),
                                  ("controlledProperty", "ControlledPropertyType")):
                    if name in kv:
                        sub = _validator(f"{SDM}definitions/{ref}")
                        out += [f"Device (key-values): {name}: {e.message}"
                                for e in sub.iter_errors(kv[name])]
    elif kind in OWN_TYPES:
        own = _validator(f"{ENTITIES}#/$defs/{kind}")
        out += [f"{kind}: {_where(e)}: {e.message}" for e in own.iter_errors(payload)]
    else:
        out.append(f"type: {kind!r} is not a Serra payload type")
    if "idempotencyKey" not in payload:
        out.append("idempotencyKey: missing")
    return out


def check(payload: Mapping[str, Any]) -> None:
    """Raise :class:`PayloadError` listing every problem of ``payload``."""
    problems = errors(payload)
    if problems:
        raise PayloadError(f"{payload.get('type')} {payload.get('id')}: " + "; ".join(problems))


def _where(e: Any) -> str:
    return "/".join(map(str, e.absolute_path)) or "<root>"

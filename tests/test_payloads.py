"""Payloads: every kind validates offline against the shipped schemas (FIWARE key-values
projection + our NGSI-LD shape); wrong ones are refused with the path; the FIWARE files are the
published bytes; nothing is fetched."""

from __future__ import annotations

import copy
import hashlib
import json
import re

import pytest
from referencing.exceptions import NoSuchResource

from gateway.cloud.store import parse
from gateway.publish import payloads as P
from gateway.publish import validate as V

PLACE = P.Place("farm1", "north", 36.79, -2.72)
T = 1_257_000_000.0
READING = P.Reading(7, 2, 15, T, {"t_in": (21.5, 0), "rh_in": (61.0, 1), "t_out": (None, 0x11),
                                  "rh_out": (None, 0x11), "i_glob": (312.5, 0), "wind": (2.5, 0),
                                  "rain": (1.0, 0)})


def every_kind() -> dict[str, dict]:
    return {
        "measurement/inside": P.weather_observed(PLACE, "inside", READING, "i"),
        "measurement/outside": P.weather_observed(PLACE, "outside", READING, "o"),
        "status": P.agri_greenhouse(PLACE, T, [7, 8], "s", rh_in=61.0, t_in=21.5,
                                    state={"estimatorState": "running", "outboxPending": 3}),
        "device/7": P.device("farm1", 7, T, "d", state="ok", boot=3, records=10, lost=4, last_seen=T,
                             channels={"t_in": "ok", "t_out": "timeout"}, greenhouses=[PLACE]),
        "forecast": P.forecast(PLACE, T, "f", model="prototype", outlook="hold-latest", t_in=20.0,
                               horizons=[(15, 20.1), (30, 20.3), (60, 20.9)]),
        "parameters": P.parameters(PLACE, T, "p", model="prototype", values=[
            P.ParameterValue("c_solar", 5e-5, "kg K J-1", 0.0, 1e-3),
            P.ParameterValue("c_cnd_cnv", 6.5, "W m-2 K-1", 1.0, 300.0)]),
        "fluxes": P.fluxes(PLACE, T, "q", model="prototype", values={"q_solar": 30.0, "q_loss": -12.0}),
        "ventilation": P.ventilation(PLACE, T, "v", flow=1.2, heat_loss=-40.0, out_of_range=True),
        "finding": P.finding(PLACE, "fi", finding_id="solar_gain_change-20091105T1000Z",
                             effect="solar_gain_change", start=T, first_seen=T, last_seen=T,
                             revision=1, detail={"params": {"factor": 0.5, "unit": "-"},
                                                 "summary": "cover whitened", "evidence": "x"}),
        "diagnosis": P.diagnosis_run(PLACE, "dr", when=T, ok=True, findings=1,
                                     note="diagnosis of 2.0 days in 9 s: 1 finding(s)",
                                     notes=[{"code": "site_time_mismatch", "level": "warning",
                                             "message": "daylight at night"},
                                            {"code": "short_heldout", "level": "note",
                                             "message": "few held-out days"}]),
    }


@pytest.mark.parametrize("kind", list(every_kind()))
def test_every_kind_is_valid(kind: str) -> None:
    payload = json.loads(P.dumps(every_kind()[kind]))  # as it travels
    assert V.errors(payload) == []
    assert payload["idempotencyKey"]["value"]


def test_units_times_and_links_follow_the_models() -> None:
    k = every_kind()
    inside, outside, gh = k["measurement/inside"], k["measurement/outside"], k["status"]
    assert inside["temperature"] == {"type": "Property", "value": 21.5, "unitCode": "CEL",
                                     "observedAt": "2009-10-31T14:40:00Z"}
    assert inside["relativeHumidity"]["value"] == 0.61 and inside["relativeHumidity"]["unitCode"] == "C62"
    assert inside["relativeHumidity"]["sensorStatus"]["value"] == "partial"
    assert outside["solarRadiation"]["unitCode"] == "D54" and outside["windSpeed"]["unitCode"] == "MTS"
    assert "temperature" not in outside  # a failed read is absent, never made up
    assert outside["missingChannels"]["value"] == {"t_out": "timeout", "rh_out": "timeout"}
    assert [r["object"] for r in gh["hasWeatherObserved"]] == [inside["id"], outside["id"]]
    assert len(list(V.projections(gh))) == 2  # each link checked against the model
    assert k["forecast"]["airTemperatureForecast"][2]["validAt"]["value"]["@value"] == "2009-10-31T15:40:00Z"
    assert k["parameters"]["c_cnd_cnv"]["unitCode"] == "D55"
    assert k["parameters"]["c_solar"]["unitText"]["value"] == "kg K J-1"  # no UN/CEFACT code


def test_a_diagnosis_run_says_when_how_it_went_and_what_it_noted() -> None:
    """The run as the gateway keeps it (``DiagnosisRun``), in the entity's own attributes; a
    note of a level the screen does not know reads as a note, never as a warning, and a failed
    run without words still has a summary."""
    d = every_kind()["diagnosis"]
    assert d["id"] == "urn:ngsi-ld:GreenhouseDiagnosisRun:serra:farm1:north"
    assert d["refAgriGreenhouse"]["object"] == every_kind()["status"]["id"]
    assert d["dateObserved"]["value"]["@value"] == "2009-10-31T14:40:00Z"
    assert (d["succeeded"]["value"], d["findingCount"]["value"]) == (True, 1)
    assert [n["level"] for n in d["runNotes"]["value"]] == ["warning", "note"]
    odd = P.diagnosis_run(PLACE, "x", when=T, ok=False, note="", findings=0,
                          notes=[{"code": "c", "level": "info", "message": "m"}, {}])
    assert odd["runNotes"]["value"] == [{"code": "c", "level": "note", "message": "m"},
                                        {"code": "?", "level": "note", "message": ""}]
    assert odd["summary"]["value"] == "diagnosis failed"
    assert V.errors(json.loads(P.dumps(odd))) == []
    # the cloud store keeps every kind alike, indexed by its observation time: the run's
    got = parse("serra/farm1/north/diagnosis", P.dumps(d))
    assert (got.kind, got.t, got.idem) == ("diagnosis", T, "dr")


def _break(kind: str, path: list, value) -> dict:
    p = copy.deepcopy(every_kind()[kind])
    node = p
    for key in path[:-1]:
        node = node[key]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return p


@pytest.mark.parametrize("kind, path, value, expect", [
    ("measurement/inside", ["relativeHumidity", "value"], 61.0, "relativeHumidity: 61.0 is greater"),
    ("measurement/inside", ["dateObserved", "value", "@value"], "31/10/2009", "is not a 'date-time'"),
    ("measurement/inside", ["location"], KeyError, "'location' is a required property"),
    ("measurement/outside", ["windSpeed", "value"], -1.0, "windSpeed: -1.0 is less than"),
    ("measurement/outside", ["windSpeed", "value"], None, "ngsi-ld: windSpeed"),
    ("measurement/outside", ["windSpeed", "unitCode"], "m/s", "ngsi-ld: windSpeed"),
    ("status", ["hasAgriParcelParent"], KeyError, "'hasAgriParcelParent' is a required"),
    ("device/7", ["controlledProperty", "value"], ["temperature", "banana"], "'banana' is not one of"),
    ("device/7", ["controlledProperty"], KeyError, "'controlledProperty' is a required"),
    ("forecast", ["airTemperatureForecast", 0, "unitCode"], "KEL", "airTemperatureForecast/0/unitCode"),
    ("ventilation", ["ventilationFlow", "value"], -0.5, "ventilationFlow/value"),
    ("finding", ["idempotencyKey"], KeyError, "idempotencyKey"),
    ("diagnosis", ["succeeded", "value"], "yes", "succeeded/value"),
    ("diagnosis", ["findingCount", "value"], -1, "findingCount/value"),
    ("diagnosis", ["runNotes", "value", 0, "level"], "loud", "runNotes/value/0/level"),
    ("diagnosis", ["runNotes", "value", 1, "code"], KeyError, "'code' is a required"),
    ("diagnosis", ["summary"], KeyError, "'summary' is a required"),
])
def test_wrong_payloads_are_refused_naming_the_attribute(kind, path, value, expect) -> None:
    problems = V.errors(_break(kind, path, value))
    assert any(expect in p for p in problems), problems
    with pytest.raises(V.PayloadError):
        V.check(_break(kind, path, value))


def test_shipped_fiware_files_are_the_published_bytes_and_nothing_is_fetched() -> None:
    folder = V.SCHEMAS / "fiware"
    source = (folder / "SOURCE.md").read_text()
    files = sorted(folder.glob("*.json"))
    assert len(files) == 8
    for f in files:
        row = next(line for line in source.splitlines() if line.startswith(f"| {f.name} |"))
        assert hashlib.sha256(f.read_bytes()).hexdigest() in row, f.name
    for name in ("LICENSE-CC-BY-4.0.md", "NOTICE.md", "README.md"):
        assert (folder / name).stat().st_size > 200
    with pytest.raises(NoSuchResource):
        V.registry().get_or_retrieve("https://smart-data-models.github.io/dataModel.Weather/other.json")
    assert re.search(r"CC BY 4\.0", (folder / "NOTICE.md").read_text())

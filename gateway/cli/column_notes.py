"""Notes on the optional kit columns a run reads but the data lacks (docs/data-format.md,
"Notes"): what the gateway uses in their place and what that costs.

Which columns a run reads: the flux terms' ``optional`` (gateway/model/terms.py), plus the
outside humidity for ``replay`` (its ARX baseline reads the sky temperature,
gateway/estimate/arx.py) and ``diagnose`` (its base tries a sky loss part, and its humidity
evidence reads both humidities, gateway/diagnose/humidity.py). Each function returns
(code, message) pairs; gateway/cli/notes.py makes them notes.
"""

from __future__ import annotations

import numpy as np

from gateway.greenhouse import Greenhouse
from gateway.model.model import Model
from gateway.model.sky import WITHOUT_HUMIDITY
from gateway.series import Series

SKY_COMMANDS = ("replay", "diagnose")
"""Commands that read the sky temperature whatever the model (see the module docstring)."""
NO_VENT_COMMANDS = ("vsensor",)
"""Commands whose model runs without the vent openings by design (vsensor's inputs are its
replay without them, docs/vsensor.md): no note for openings the data lacks; they decide only
whether the run is scored against the explicit flow (``reference`` null without them)."""
HUMIDITY_EVIDENCE = ("the diagnosis's humidity evidence (the night vapour balance that tells "
                     "more air exchange from less sun, docs/effects.md, \"Humidity evidence\") "
                     "is off, and the temperatures alone decide")


def reads(model: Model) -> set[str]:
    """The optional kit columns the model's flux terms read when the data has them."""
    return {c for term in model.terms for c in getattr(term, "optional", ())}


def missing(series: Series, name: str) -> str | None:
    """How column ``name`` is missing as a whole ("no column rh_out", "column rh_out is
    empty": every grid row without a value); None when it has a value somewhere."""
    if name not in series.columns:
        return f"no column {name}"
    if name not in series:
        return f"column {name} is empty"
    return None


def empty_rows(series: Series, name: str, where: str | None = None) -> int:
    """Grid rows where column ``name`` has a value somewhere but not there (and ``where``,
    when given, has one)."""
    v = series.columns[name]
    gap = ~np.isfinite(v)
    if where is not None and where in series.columns:
        gap &= np.isfinite(series.columns[where])
    return int(gap.sum())


def column_notes(series: Series, gh: Greenhouse, model: Model, data: str,
                 command: str | None) -> list[tuple[str, str]]:
    """(code, message) of every optional column the run reads and the data lacks."""
    used = reads(model)
    out = outside_humidity(series, data, "rh_out" in used or command in SKY_COMMANDS,
                           command == "diagnose")
    if command == "diagnose" and "rh_in" not in model.requires:
        how = missing(series, "rh_in")
        if how:
            out.append(("no_rh_in", f"{data}: {how} (inside relative humidity): "
                        f"{HUMIDITY_EVIDENCE}"))
    if {"vent_roof", "vent_side"} & used and command not in NO_VENT_COMMANDS:
        out += vent_openings(series, gh, model, data)
    if "lai" in used and missing(series, "lai"):
        zero = " (0: no transpiration at all)" if gh.crop.lai <= 0 else ""
        out.append(("no_lai", f"{data}: {missing(series, 'lai')} (leaf area index): the "
                    f"'{model.name}' model's transpiration takes the greenhouse's [crop] lai, "
                    f"{gh.crop.lai:g} m2 m-2{zero}, on every row: a crop that grew or was "
                    "cleared is not seen"))
    if model.radiation is not None and missing(series, "i_in"):
        name = model.radiation.parameter.name
        out.append(("no_i_in", f"{data}: {missing(series, 'i_in')} (radiation under the "
                    f"cover): the cover transmission {name} of the '{model.name}' model is not "
                    "estimated from the data and keeps its starting value (the greenhouse's "
                    "[cover] transmission, or --params); a change of the cover is judged on the "
                    "temperatures alone"))
    return out


def outside_humidity(series: Series, data: str, sky: bool, evidence: bool) -> list[tuple[str, str]]:
    """The note when the sky temperature (``sky``: the run reads it) or the humidity evidence
    (``evidence``: diagnose) lacks the outside humidity: the clear-sky emissivity then comes
    from the outside air temperature alone (Swinbank 1963) instead of its vapour pressure
    (Brutsaert 1975; gateway/model/sky.py ``clear_sky_emissivity``)."""
    if not (sky or evidence):
        return []
    how = missing(series, "rh_out")
    if how:
        parts = ([WITHOUT_HUMIDITY] if sky else []) + ([HUMIDITY_EVIDENCE] if evidence else [])
        return [("no_rh_out", f"{data}: {how} (outside relative humidity): "
                 + "; and ".join(parts))]
    n = empty_rows(series, "rh_out", where="t_out")
    if n and sky:
        return [("rh_out_gaps", f"{data}: column rh_out is empty on {n} of {len(series)} rows "
                 f"on the {series.step:g} s grid that have an outside temperature: there {WITHOUT_HUMIDITY}")]
    return []


def vent_openings(series: Series, gh: Greenhouse, model: Model, data: str) -> list[tuple[str, str]]:
    """Notes for vent opening columns the greenhouse's vents need and the data lacks: the
    model then takes those vents as closed (gateway/model/drivers.py, ``prepare_drivers``)."""
    out = []
    for name, kind, count in (("vent_roof", "roof", gh.vents.roof_count),
                              ("vent_side", "side", gh.vents.side_count)):
        if count <= 0:
            continue
        how = missing(series, name)
        cost = (f"the '{model.name}' model takes the {kind} vents ({count} in the greenhouse "
                "description) as closed, so heat they carried out while open is put on other "
                "terms or left in the residual")
        if how:
            out.append(("no_vent_opening", f"{data}: {how} ({kind} vent opening, %): {cost} on "
                        "every row"))
        elif n := empty_rows(series, name):
            out.append(("vent_opening_gaps", f"{data}: column {name} is empty on {n} of "
                        f"{len(series)} rows on the {series.step:g} s grid: there {cost}"))
    return out

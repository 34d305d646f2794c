"""The Zenoh key space and the history selector (docs/cloud.md).

    serra/<farm>/<greenhouse>/<kind>
    serra/<farm>/<greenhouse>/history/<kind>?from=ISO;to=ISO;limit=N
    serra/<farm>/<greenhouse>/history/<kind>?last=N          (the newest N of each key)

``kind`` is one of :data:`KINDS` or ``device/<id>``. Devices that no greenhouse of the config
uses are reported under the greenhouse name ``unassigned``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime

PREFIX = "serra"
KINDS = ("measurement/inside", "measurement/outside", "forecast", "parameters", "fluxes",
         "ventilation", "finding", "diagnosis", "status")
UNASSIGNED = "unassigned"
HISTORY = "history"
DEFAULT_LIMIT = 1000
MAX_LIMIT = 100_000


def key(farm: str, greenhouse: str, kind: str) -> str:
    return f"{PREFIX}/{farm}/{greenhouse}/{kind}"


def device_kind(device_id: int) -> str:
    return f"device/{device_id}"


def history_key(message_key: str) -> str:
    """``serra/f/g/<kind>`` → ``serra/f/g/history/<kind>`` (where a history reply is sent)."""
    prefix, farm, greenhouse, kind = message_key.split("/", 3)
    return f"{prefix}/{farm}/{greenhouse}/{HISTORY}/{kind}"


def split(message_key: str) -> tuple[str, str, str]:
    """``serra/f/g/<kind>`` → (farm, greenhouse, kind); ValueError for another key."""
    parts = message_key.split("/", 3)
    if len(parts) != 4 or parts[0] != PREFIX or parts[3].startswith(HISTORY + "/"):
        raise ValueError(f"not a Serra message key: {message_key!r}")
    return parts[1], parts[2], parts[3]


class SelectorError(ValueError):
    """A history query's parameters cannot be used (the reply error says which)."""


@dataclass(frozen=True)
class HistoryRange:
    start: float  # [unix s], -inf when absent
    end: float  # [unix s] included, +inf when absent
    limit: int
    last: int | None = None  # the newest ``last`` messages of each key in the range (still
    # replied oldest first, at most ``limit`` in all), e.g. ``last=1``: the latest of every key


def parse_time(text: str, name: str) -> float:
    """ISO 8601 (``2009-11-01T00:00:00Z``; no offset = UTC) → unix seconds."""
    try:
        dt = datetime.fromisoformat(text.strip())
    except ValueError:
        raise SelectorError(f"{name}={text!r}: expected an ISO time like 2009-11-01T00:00:00Z") from None
    if dt.tzinfo is None:
        from datetime import UTC

        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def parse_range(get) -> HistoryRange:
    """Selector parameters (``get(name) -> str | None``) → :class:`HistoryRange`."""
    start = parse_time(v, "from") if (v := get("from")) else -math.inf
    end = parse_time(v, "to") if (v := get("to")) else math.inf
    text = get("limit")
    if text:
        if not text.strip().isdigit() or not 1 <= int(text) <= MAX_LIMIT:
            raise SelectorError(f"limit={text!r}: expected a whole number in 1..{MAX_LIMIT}")
        limit = int(text)
    else:
        limit = DEFAULT_LIMIT
    if start > end:
        raise SelectorError("from is after to")
    last = None
    if text := get("last"):
        if not text.strip().isdigit() or not 1 <= int(text) <= MAX_LIMIT:
            raise SelectorError(f"last={text!r}: expected a whole number in 1..{MAX_LIMIT}")
        last = int(text)
    return HistoryRange(start, end, limit, last)


def query_range(query) -> HistoryRange | None:
    """The range a Zenoh history query asks for; ``None`` once the query has been answered with
    the error (a bad selector parameter names itself)."""
    try:
        return parse_range(lambda name: query.parameters.get(name))
    except SelectorError as e:
        query.reply_err(str(e))
        return None

"""A history query's key expression → what a cloud store can filter on.

The cloud store answers ``serra/<farm>/<greenhouse>/history/<kind>`` queries (docs/cloud.md)
from a table indexed by farm, greenhouse, kind and time. :func:`history_filter` pulls the
literal parts of the asked key expression out for the SQL ``WHERE`` (so the indexes serve the
query) and keeps a predicate that decides exactly, on each candidate row's message key, whether
its history key is one the query asked for (Zenoh's wildcards: ``*`` one chunk, ``**`` any
number of chunks, ``$*`` part of a chunk). Tested against Zenoh's own ``KeyExpr.intersects``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from gateway.publish import keyspace as K

_META = set(r".^$*+?()[]{}|\-")


def _chunk(chunk: str) -> str:
    if chunk == "*":
        return "[^/]+"
    out = []
    for i, part in enumerate(chunk.split("$*")):
        if i:
            out.append("[^/]*")
        out.append("".join("\\" + c if c in _META else c for c in part))
    return "".join(out)


def regex(key_expr: str) -> re.Pattern[str]:
    """A pattern that matches ``"/" + key`` for every concrete key the expression includes."""
    parts = []
    for chunk in key_expr.strip("/").split("/"):
        parts.append("(?:/[^/]+)*" if chunk == "**" else "/" + _chunk(chunk))
    return re.compile("^" + "".join(parts) + "$")


def _literal(chunk: str) -> bool:
    return "*" not in chunk and "$" not in chunk


@dataclass(frozen=True)
class HistoryFilter:
    """Literal parts of a history query (None: any) and the exact test on a message key."""

    farm: str | None
    greenhouse: str | None
    kind: str | None  # exact, or "stem/**" for every kind below stem
    pattern: re.Pattern[str]

    def wants(self, message_key: str) -> bool:
        """Whether the query asked for this message (its history key matches)."""
        return bool(self.pattern.match("/" + K.history_key(message_key)))


def history_filter(key_expr: str) -> HistoryFilter:
    chunks = key_expr.strip("/").split("/")
    farm = chunks[1] if len(chunks) > 1 and chunks[0] == K.PREFIX and _literal(chunks[1]) else None
    greenhouse = kind = None
    if len(chunks) >= 5 and chunks[0] == K.PREFIX and chunks[3] == K.HISTORY and "**" not in chunks[:4]:
        greenhouse = chunks[2] if _literal(chunks[2]) else None
        rest = chunks[4:]
        if all(_literal(c) for c in rest):
            kind = "/".join(rest)
        elif rest[-1] == "**" and len(rest) > 1 and all(_literal(c) for c in rest[:-1]):
            kind = "/".join(rest)
    return HistoryFilter(farm, greenhouse, kind, regex(key_expr))

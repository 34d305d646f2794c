"""Catch-up: after the cloud subscriber (re)joins, it asks the gateways' history for what it may
not have received live, and stores the replies like live samples (repeats are dropped by
idempotency key).

Live delivery alone cannot promise a complete cloud copy: a gateway marks a message sent once
Zenoh took it, and a sample can still be lost on the way (a link cut before the gateway sees its
subscriber go, or a store restarted right after a put). The gateway's store keeps every message
it made for ``history_days`` and answers ``serra/<farm>/<greenhouse>/history/<kind>``
(gateway/publish/history.py), so on each join the subscriber asks, per subscription, for the
messages observed since shortly before the newest one it holds of that farm (everything the
gateways keep for a farm it holds nothing of). A subscription over every farm (``serra/**``) is
asked farm by farm: the farms are those the store holds and those a ``?last=1`` query finds, so
a farm that joined the fleet while the subscriber was away gets its older history too (one
start time for all farms would leave it out). The query goes to every queryable
(``QueryTarget.ALL``; remote ones only, not this store's own history queryable), and is paged by
observation time when a gateway's replies reach the limit.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime

from gateway.publish import keyspace as K

log = logging.getLogger("serra.cloud")
MARGIN_S = 3600.0  # [s] asked again before the newest stored observation (keys drain apart)
PAGE = K.MAX_LIMIT  # replies per gateway per query
TIMEOUT_S = 120.0  # [s] per query: a page of 100 000 replies takes seconds on a Pi


@dataclass
class CatchUpStats:
    queries: int = 0
    replies: int = 0  # history replies handed to the store (new or repeats)
    errors: list[str] = field(default_factory=list)  # error replies and failed queries


def history_selector(subscription: str) -> str:
    """The history key expression under a subscription: ``serra/**`` → ``serra/*/*/history/**``,
    ``serra/<farm>/**`` → ``serra/<farm>/*/history/**``, ``serra/f/g/<kind>`` →
    ``serra/f/g/history/<kind>``; ValueError for one that names no farm level."""
    parts = subscription.split("/")
    if parts[0] != K.PREFIX or len(parts) < 2:
        raise ValueError(f"not a Serra subscription: {subscription!r}")
    if parts[1] == "**":
        return f"{K.PREFIX}/*/*/{K.HISTORY}/**"
    if len(parts) == 2 or parts[2] == "**":
        return f"{K.PREFIX}/{parts[1]}/*/{K.HISTORY}/**"
    kind = "/".join(parts[3:]) or "**"
    return f"{K.PREFIX}/{parts[1]}/{parts[2]}/{K.HISTORY}/{kind}"


def message_key(history_key: str) -> str:
    """``serra/f/g/history/<kind>`` → ``serra/f/g/<kind>`` (the key the sample was put on)."""
    prefix, farm, greenhouse, hist, kind = history_key.split("/", 4)
    if prefix != K.PREFIX or hist != K.HISTORY:
        raise ValueError(f"not a history key: {history_key!r}")
    return f"{prefix}/{farm}/{greenhouse}/{kind}"


def since(subscription: str, latest: Mapping[str, float]) -> float | None:
    """Where to start asking [unix s]: the newest observation stored of the subscription's farm
    (of every farm stored for a ``serra/**`` one, the oldest of them) less :data:`MARGIN_S`;
    None (everything kept) when the store holds nothing of it."""
    farm = subscription.split("/")[1]
    if farm in ("**", "*"):
        return min(latest.values()) - MARGIN_S if latest else None
    return latest[farm] - MARGIN_S if farm in latest else None


def per_farm(subscription: str, farms: Iterable[str]) -> list[str]:
    """A subscription over every farm (``serra/**``, ``serra/*/north/**``) as one subscription per
    farm in ``farms`` (sorted); any other subscription as itself."""
    parts = subscription.split("/")
    if len(parts) < 2 or parts[1] not in ("**", "*"):
        return [subscription]
    rest = parts[2:] if parts[1] == "*" else ["**"]  # serra/**/x is asked whole, as before
    return [f"{K.PREFIX}/{farm}/" + "/".join(rest) for farm in sorted(set(farms))]


def farms_answering(session, cancel) -> set[str]:
    """The farms whose gateways answer history: one ``?last=1`` query (one reply per key)."""
    import zenoh

    found: set[str] = set()
    replies = session.get(f"{K.PREFIX}/*/*/{K.HISTORY}/**?last=1", target=zenoh.QueryTarget.ALL,
                          consolidation=zenoh.ConsolidationMode.NONE,
                          allowed_destination=zenoh.Locality.REMOTE, timeout=TIMEOUT_S,
                          cancellation_token=cancel)
    for r in replies:
        if r.ok is not None:
            found.add(str(r.ok.key_expr).split("/")[1])
    return found


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def catch_up(session, subscriptions: Sequence[str], latest: Mapping[str, float],
             deliver: Callable[[str, bytes], None], cancel=None) -> CatchUpStats:
    """Ask the history under each subscription from :func:`since`; every reply goes to
    ``deliver(message_key, payload)``. Paged: a farm whose replies reach :data:`PAGE` is asked
    again from its newest reply's time. ``cancel``: a ``zenoh.CancellationToken`` that ends it."""
    import zenoh

    stats = CatchUpStats()
    cancel = cancel if cancel is not None else zenoh.CancellationToken()
    for sub in _expanded(session, subscriptions, latest, stats, cancel):
        try:
            selector = history_selector(sub)
        except ValueError as e:
            stats.errors.append(str(e))
            continue
        start = since(sub, latest)
        while not cancel.is_cancelled:
            params = f"limit={PAGE}" + (f";from={_iso(start)}" if start is not None else "")
            stats.queries += 1
            per_farm: dict[str, tuple[int, float]] = {}  # farm → (replies, newest t)
            try:
                replies = session.get(f"{selector}?{params}", target=zenoh.QueryTarget.ALL,
                                      consolidation=zenoh.ConsolidationMode.NONE,
                                      allowed_destination=zenoh.Locality.REMOTE,
                                      timeout=TIMEOUT_S, cancellation_token=cancel)
                for r in replies:
                    if r.ok is None:
                        stats.errors.append(f"{selector}: {r.err.payload.to_string()}")
                        continue
                    key = message_key(str(r.ok.key_expr))
                    payload = r.ok.payload.to_bytes()
                    deliver(key, payload)
                    stats.replies += 1
                    farm = key.split("/")[1]
                    n, t = per_farm.get(farm, (0, -math.inf))
                    per_farm[farm] = (n + 1, max(t, _observed(payload)))
            except Exception as e:  # a closing session, a malformed reply: say it, go on
                stats.errors.append(f"{selector}: {e}")
                break
            full = [t for n, t in per_farm.values() if n >= PAGE and math.isfinite(t)]
            if not full or (start is not None and min(full) <= start):
                break  # done, or no progress (a page of one instant): not asked again
            start = min(full)
            log.info("catch-up: %s full page, asking again from %s", selector, _iso(start))
    return stats


def _expanded(session, subscriptions: Sequence[str], latest: Mapping[str, float],
              stats: CatchUpStats, cancel) -> list[str]:
    """The subscriptions to ask, those over every farm split per farm (:func:`per_farm`); if the
    farms cannot be found, such a subscription is asked whole from :func:`since`, as one."""
    if cancel.is_cancelled or all(per_farm(sub, ()) == [sub] for sub in subscriptions):
        return list(subscriptions)
    try:
        farms = set(latest) | farms_answering(session, cancel)
    except Exception as e:  # a closing session: ask as before
        stats.errors.append(f"finding the farms: {e}")
        return list(subscriptions)
    stats.queries += 1
    return [one for sub in subscriptions for one in per_farm(sub, farms)]


def _observed(payload: bytes) -> float:
    from gateway.cloud.store import NotAMessage, parse

    try:
        t = parse("serra/x/y/z", payload).t
    except NotAMessage:
        return -math.inf
    return -math.inf if t is None else t


def run_logged(session, subscriptions: Sequence[str], latest: Mapping[str, float],
               deliver: Callable[[str, bytes], None], cancel) -> CatchUpStats:
    """:func:`catch_up` with one log line saying what it did (the subscriber's thread)."""
    t0 = time.monotonic()
    stats = catch_up(session, subscriptions, latest, deliver, cancel)
    log.info("catch-up: %d replies from %d queries in %.1f s%s", stats.replies, stats.queries,
             time.monotonic() - t0, f"; errors: {stats.errors}" if stats.errors else "")
    return stats

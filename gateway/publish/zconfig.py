"""The one place a Zenoh config is built from Serra's settings (gateway, subscriber, tools).

Security (TLS, mTLS, user/password, access control) and routers are their own issue: they add
keys here, from the same TOML, and nowhere else. ``extra`` passes raw Zenoh config keys
(``[zenoh.config]`` in the TOML: ``"transport/link/tx/lease" = 3000``) for what we do not model.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping
from typing import Any

import zenoh


def build(mode: str = "peer", connect: Iterable[str] = (), listen: Iterable[str] = (),
          multicast_scouting: bool = False, timestamping: bool = True,
          extra: Mapping[str, Any] | None = None, dial_only: bool = False) -> zenoh.Config:
    """A ``zenoh.Config``. Timestamps are on: the advanced publisher's cache needs them, and a
    subscriber can order samples by them.

    ``dial_only``: with no ``listen`` endpoint, open no listening socket at all. Zenoh's peer
    default listens on every interface at a random port; a tool that only connects out (the
    status screen's queries, a subscriber given ``--connect`` alone) has no use for it, and a
    socket on every interface is one more door on a farm's network."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    connect, listen = list(connect), list(listen)
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if listen or dial_only:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
    if timestamping:
        conf.insert_json5("timestamping/enabled", json.dumps(True))
    for key, value in (extra or {}).items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def listening_ports(pid: int | None = None) -> list[int]:
    """TCP ports this process (or process ``pid``) listens on (Linux /proc): what Zenoh bound
    for ``tcp/HOST:0``."""
    proc = f"/proc/{pid if pid is not None else 'self'}"
    inodes = set()
    for fd in os.listdir(f"{proc}/fd"):
        try:
            link = os.readlink(f"{proc}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    ports = []
    for table in (f"{proc}/net/tcp", f"{proc}/net/tcp6"):
        try:
            lines = open(table).read().splitlines()[1:]  # noqa: SIM115
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # 0A = LISTEN
                ports.append(int(f[1].rsplit(":", 1)[1], 16))
    return sorted(set(ports))


def resolve_listen(endpoints: Iterable[str], before: Iterable[int]) -> list[str]:
    """Endpoints with port 0 replaced by the port Zenoh bound (new since ``before``)."""
    fresh = [p for p in listening_ports() if p not in set(before)]
    out = []
    for e in endpoints:
        if e.startswith("tcp/") and e.endswith(":0") and fresh:
            out.append(f"{e[:-2]}:{fresh.pop(0)}")
        else:
            out.append(e)
    return out

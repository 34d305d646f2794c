"""The gateway's TOML config: devices → greenhouses, store, ingest, Zenoh, estimator, diagnosis.

Validated at start: every error names the file and the key (``gateway.toml: greenhouse[2].inside:
device 9 has no key in /etc/serra/keys.txt``). The documented example is
``images/gateway/gateway.toml``; docs/gateway.md explains every key.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

from gateway.ingest.service import parse_hostport
from gateway.net.tomlcheck import ConfigError
from gateway.net.zenohcfg import Retry, TlsFiles
from gateway.service.settings import (
    ClockSettings,
    DiagnosisSettings,
    EstimatorSettings,
    GatewayConfig,
    GreenhouseSettings,
    ZenohSettings,
)
from gateway.store.retention import MIN_DAYS, MIN_DB_MB
from gateway.tomlfile import read_toml

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,62}$")
"""Farm and greenhouse names: one Zenoh key chunk (no /, *, $, ?, #, @), at most 63 characters."""
RESERVED = {"unassigned", "history"}
"""Greenhouse names the key space uses itself."""
_REQUIRED = object()


class _Table:
    """One TOML table being read: typed getters and a check that no unknown key is left."""

    def __init__(self, source: str, path: str, raw: Any) -> None:
        self.source, self.path = source, path
        if not isinstance(raw, dict):
            self.fail("", "must be a table")
        self.raw: dict[str, Any] = raw
        self.seen: set[str] = set()

    def where(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path and key else (self.path or key)

    def fail(self, key: str, what: str) -> None:
        raise ConfigError(f"{self.source}: {self.where(key)}: {what}")

    def get(self, key: str, kind: type, default: Any = _REQUIRED, lo: float | None = None,
            hi: float | None = None, choices: tuple | None = None) -> Any:
        self.seen.add(key)
        if key not in self.raw:
            if default is _REQUIRED:
                self.fail(key, "missing (required)")
            return default
        v = self.raw[key]
        if kind is float and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        if not isinstance(v, kind) or (isinstance(v, bool) and kind is not bool):
            self.fail(key, f"must be {_kind_name(kind)}, got {v!r}")
        if kind is float and not math.isfinite(v):
            self.fail(key, f"must be a finite number, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            self.fail(key, f"{v:g} is outside {lo:g}..{hi:g}" if lo is not None and hi is not None
                      else f"{v:g} is below its minimum {lo:g}" if lo is not None
                      else f"{v:g} is above its maximum {hi:g}")
        if choices is not None and v not in choices:
            self.fail(key, f"{v!r} is not one of {', '.join(map(str, choices))}")
        return v

    def sub(self, key: str) -> _Table:
        self.seen.add(key)
        return _Table(self.source, self.where(key), self.raw.get(key, {}))

    def done(self) -> None:
        extra = sorted(set(self.raw) - self.seen)
        if extra:
            self.fail(extra[0], f"unknown key (allowed here: {', '.join(sorted(self.seen))})")


def defaults(cls: type) -> dict[str, Any]:
    """A settings dataclass's defaults by field name (a factory's made afresh): the parsers take
    a missing key's value from here, so a default is written once, in the dataclass."""
    out: dict[str, Any] = {}
    for f in fields(cls):
        if f.default is not MISSING:
            out[f.name] = f.default
        elif f.default_factory is not MISSING:
            out[f.name] = f.default_factory()
    return out


def _kind_name(kind: type) -> str:
    return {str: "a string", int: "a whole number", float: "a number", bool: "true or false",
            list: "a list", dict: "a table"}.get(kind, kind.__name__)


def _path(base: Path, text: str) -> Path:
    p = Path(text).expanduser()
    return p if p.is_absolute() else base / p


def _hostport(t: _Table, key: str,
              default: tuple[str, int] | None) -> tuple[str, int] | None:
    """``HOST:PORT`` (``""``: None, no such transport); ``default`` when the key is absent."""
    text = t.get(key, str, None)
    if text is None:
        return default
    if not text:
        return None
    try:  # the ingest command's own reading of --listen, one place
        return parse_hostport(text)
    except argparse.ArgumentTypeError as exc:
        t.fail(key, str(exc))  # raises ConfigError
    return None  # not reached


def _endpoints(t: _Table, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
    items = t.get(key, list, list(default))
    for i, e in enumerate(items):
        if not isinstance(e, str) or not re.match(r"^[a-z0-9]+/.+", e):
            t.fail(f"{key}[{i}]", f"expected a Zenoh endpoint like 'tcp/192.168.1.10:7447', got {e!r}")
    return tuple(items)


def _time(t: _Table, key: str, default: float | None) -> float | None:
    import numpy as np

    v = t.get(key, str, None) if isinstance(t.raw.get(key), str) else t.get(key, float, default)
    if isinstance(v, str):
        try:
            return float(np.datetime64(v.rstrip("Z"), "s").astype("int64"))
        except ValueError:
            t.fail(key, f"expected an ISO UTC time like 2009-11-01T00:00:00Z, got {v!r}")
    return v


def load_config(path: str | Path) -> GatewayConfig:
    """Read and validate ``path``; raises :class:`ConfigError` naming the key."""
    path = Path(path)
    raw = read_toml(path, ConfigError, "gateway config")
    return parse_config(raw, str(path), path.resolve().parent)


def parse_config(raw: dict[str, Any], source: str = "<config>", base: Path = Path(".")) -> GatewayConfig:
    top = _Table(source, "", raw)
    d = defaults(GatewayConfig)
    g = top.sub("gateway")
    farm = g.get("farm", str)
    if not NAME.match(farm):
        g.fail("farm", f"{farm!r} is not usable in a Zenoh key (letters, digits, _ . -)")
    db = _path(base, g.get("db", str))
    keys = _path(base, g.get("keys", str))
    log_level = g.get("log_level", str, d["log_level"], choices=("debug", "info", "warning", "error"))
    status_every = g.get("status_every_s", float, d["status_every_s"], lo=1.0)
    g.done()
    ing = top.sub("ingest")
    listen = _hostport(ing, "listen", d["listen"])
    serial = ing.get("serial", str, d["serial"]) or None  # "" is none too
    baud = ing.get("baudrate", int, d["baudrate"], lo=300, hi=4_000_000)
    retention = ing.get("retention_days", float, d["retention_days"], lo=MIN_DAYS)
    history = ing.get("history_days", float, d["history_days"], lo=0.01)
    estimates_days = ing.get("estimates_days", float, d["estimates_days"], lo=MIN_DAYS)
    max_db = ing.get("max_db_mb", float, d["max_db_mb"], lo=MIN_DB_MB)
    maint = ing.get("maintenance_s", float, d["maintenance_s"], lo=0.05)
    ing.done()
    if listen is None and serial is None:
        ing.fail("listen", "no transport: set listen (UDP) or serial")
    loc = top.sub("location")
    lat = loc.get("latitude", float, None, lo=-90, hi=90)
    lon = loc.get("longitude", float, None, lo=-180, hi=180)
    loc.done()
    zen = _zenoh(top.sub("zenoh"), base, farm)
    ob = top.sub("outbox")
    outbox_max = ob.get("max_messages", int, d["outbox_max"], lo=10)
    outbox_alarm = ob.get("alarm_fraction", float, d["outbox_alarm"], lo=0.05, hi=1.0)
    ob.done()
    est = _estimator(top.sub("estimator"))
    dia = _diagnosis(top.sub("diagnosis"))
    clock = _clock(top.sub("clock"))
    top.seen.add("greenhouse")
    items = raw.get("greenhouse", [])
    if not isinstance(items, list) or not items:
        top.fail("greenhouse", "at least one [[greenhouse]] table is required")
    ghs = tuple(_greenhouse(_Table(source, f"greenhouse[{i + 1}]", item), base, lat, lon,
                            est_outlook=top.raw.get("estimator", {}).get("outlook"))
                for i, item in enumerate(items))
    names = [x.name for x in ghs]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ConfigError(f"{source}: greenhouse[{i + 1}].name: {n!r} is used twice")
    top.done()
    return GatewayConfig(
        source=source, farm=farm, db=db, keys=keys, listen=listen, serial=serial, baudrate=baud,
        retention_days=retention, history_days=history, estimates_days=estimates_days,
        max_db_mb=max_db, maintenance_s=maint,
        greenhouses=ghs, zenoh=zen, estimator=est, diagnosis=dia, clock=clock,
        outbox_max=outbox_max, outbox_alarm=outbox_alarm, status_every_s=status_every,
        log_level=log_level)


def _zenoh(z: _Table, base: Path, farm: str) -> ZenohSettings:
    d, r = defaults(ZenohSettings), defaults(Retry)
    retry = Retry(z.get("retry_initial_ms", int, r["initial_ms"], lo=10, hi=3_600_000),
                  z.get("retry_max_ms", int, r["max_ms"], lo=10, hi=3_600_000))
    s = ZenohSettings(
        enabled=z.get("enabled", bool, d["enabled"]),
        mode=z.get("mode", str, d["mode"], choices=("peer", "client")),
        connect=_endpoints(z, "connect", d["connect"]),
        listen=_endpoints(z, "listen", d["listen"]),
        multicast_scouting=z.get("multicast_scouting", bool, d["multicast_scouting"]),
        cache=z.get("cache", int, d["cache"], lo=1, hi=1_000_000),
        resend_on_start_s=z.get("resend_on_start_s", float, d["resend_on_start_s"], lo=0.0),
        extra=z.get("config", dict, d["extra"]),
        tls=_tls(z, base, farm),
        retry=retry,
    )
    z.done()
    if retry.max_ms < retry.initial_ms:
        z.fail("retry_max_ms", f"{retry.max_ms} is below retry_initial_ms = {retry.initial_ms}")
    if s.enabled and s.mode == "client" and not s.connect:
        z.fail("connect", "client mode needs at least one router endpoint to connect to")
    for key in ("connect", "listen"):
        for i, e in enumerate(getattr(s, key)):
            if e.startswith("tls/") and s.tls is None:
                z.fail(f"{key}[{i}]", f"{e!r} needs a [zenoh.tls] table (ca, cert, key)")
            if key == "listen" and e.startswith("tls/") and s.tls is not None and s.tls.cert is None:
                z.fail(f"{key}[{i}]", f"listening on {e!r} needs zenoh.tls.cert and zenoh.tls.key")
    return s


def _tls(z: _Table, base: Path, farm: str) -> TlsFiles | None:
    """``[zenoh.tls]`` (gateway.net.zenohcfg.parse_tls): files checked, key mode 0600, and the
    certificate's common name must be the farm (the routers' access control keys on it)."""
    from gateway.net.certs import CertError, common_name, load_certificate
    from gateway.net.tomlcheck import Table
    from gateway.net.zenohcfg import parse_tls

    raw = z.get("tls", dict, {})
    try:
        tls = parse_tls(Table(raw, z.source, z.where("tls")), base)
        cn = common_name(load_certificate(tls.cert)) if tls is not None and tls.cert else None
    except CertError as e:
        raise ConfigError(str(e)) from None
    if tls is not None and cn is not None and cn != farm:  # cn comes with tls
        z.fail("tls.cert", f"{tls.cert} is for {cn!r}, not this gateway's farm {farm!r}: the "
                           "routers' access control lets a gateway speak only under "
                           "serra/<its certificate's name>/** (python -m gateway certs --gateway FARM)")
    return tls


def _estimator(e: _Table) -> EstimatorSettings:
    from gateway.service.forecaster import KINDS

    d = defaults(EstimatorSettings)
    horizons = e.get("horizons_min", list, list(d["horizons_min"]))
    if not horizons or not all(isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= 1440
                               for h in horizons):
        e.fail("horizons_min", f"must be whole minutes in 1..1440, got {horizons!r}")
    e.get("outlook", str, None)  # checked per greenhouse (default: outlook.default_outlook)
    s = EstimatorSettings(
        horizons_min=tuple(sorted(set(horizons))),
        seed=e.get("seed", int, d["seed"], lo=0),
        max_wait_s=e.get("max_wait_s", float, d["max_wait_s"], lo=0.0),
        settle_s=e.get("settle_s", float, d["settle_s"], lo=0.0),
        gap_s=e.get("gap_s", float, d["gap_s"], lo=60.0),
        history_min=e.get("history_min", int, d["history_min"], lo=1, hi=100_000),
        forecast=e.get("forecast", str, d["forecast"], choices=KINDS),
        # at most an hour: the journal, rewritten every minute, grows ~150 bytes a minute
        snapshot_every_min=e.get("snapshot_every_min", int, d["snapshot_every_min"], lo=1,
                                 hi=60),
    )
    e.done()
    return s


def _diagnosis(d: _Table) -> DiagnosisSettings:
    f = defaults(DiagnosisSettings)
    s = DiagnosisSettings(
        enabled=d.get("enabled", bool, f["enabled"]),
        every_hours=d.get("every_hours", float, f["every_hours"], lo=0.01),
        days=d.get("days", float, f["days"], lo=0.1),
        min_days=d.get("min_days", float, f["min_days"], lo=0.05),
        timeout_s=d.get("timeout_s", float, f["timeout_s"], lo=1.0),
    )
    d.done()
    if s.min_days > s.days:
        d.fail("min_days", f"{s.min_days} is more than days = {s.days}")
    return s


def _clock(c: _Table) -> ClockSettings:
    d = defaults(ClockSettings)
    s = ClockSettings(scale=c.get("scale", float, d["scale"], lo=1e-3, hi=1e5),
                      epoch=_time(c, "epoch", d["epoch"]),
                      anchor=c.get("anchor", float, d["anchor"], lo=0.0))
    c.done()
    if s.scale != 1.0 and s.epoch is None:
        c.fail("epoch", "a scaled clock needs the time it starts from (epoch)")
    return s


def _greenhouse(t: _Table, base: Path, lat: float | None, lon: float | None,
                est_outlook: str | None) -> GreenhouseSettings:
    from gateway.estimate.outlook import OUTLOOKS, default_outlook
    from gateway.greenhouse import GreenhouseError, load_greenhouse
    from gateway.model import MODEL_NAMES

    name = t.get("name", str)
    if not NAME.match(name) or name in RESERVED:
        t.fail("name", f"{name!r} is not usable in a Zenoh key (letters, digits, _ . -; not "
                       f"{', '.join(sorted(RESERVED))})")
    spec = t.get("greenhouse", str)
    gh_path = spec if "/" not in spec and not spec.endswith(".toml") else str(_path(base, spec))
    try:
        gh = load_greenhouse(gh_path)
    except GreenhouseError as e:
        t.fail("greenhouse", str(e))
    model = t.get("model", str, choices=MODEL_NAMES)
    inside = t.get("inside", int, lo=0, hi=0xFFFFFFFF)
    outside = t.get("outside", int, inside, lo=0, hi=0xFFFFFFFF)
    params = t.get("params", str, None)
    vsensor = t.get("vsensor", str, None)
    outlook = t.get("outlook", str, est_outlook or default_outlook(gh))
    if outlook not in OUTLOOKS:
        t.fail("outlook", f"unknown weather outlook {outlook!r} (known: {', '.join(sorted(OUTLOOKS))})")
    if outlook == "clear-sky-trend" and gh.site is None:
        t.fail("outlook", f"clear-sky-trend needs the sun's position: {gh.source} has no [site] "
                          "(add latitude and longitude there, or choose hold-latest)")
    t.done()
    site = gh.site
    g_lat = site.latitude if site else lat
    g_lon = site.longitude if site else lon
    if g_lat is None or g_lon is None:
        t.fail("greenhouse", f"{gh.source} has no [site] and the config has no [location]: the "
                             "published payloads need latitude and longitude")
    return GreenhouseSettings(
        name=name, greenhouse=gh_path, model=model, inside=inside, outside=outside,
        params=_path(base, params) if params else None, outlook=outlook,
        vsensor=_path(base, vsensor) if vsensor else None, latitude=g_lat, longitude=g_lon)

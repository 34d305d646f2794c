"""The config's defaults are written once, in the settings dataclasses: a gateway.toml without a
key gets the dataclass's value, docs/gateway.md states the same values, and the shipped example
sets the defaults except where it means to differ."""

from __future__ import annotations

import re
import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from gateway.net.zenohcfg import Retry
from gateway.service import config as config_module
from gateway.service.config import defaults, load_config, parse_config
from gateway.service.settings import (
    ClockSettings,
    DiagnosisSettings,
    EstimatorSettings,
    GatewayConfig,
    ZenohSettings,
)
from tests.test_gateway_config import GOOD, with_

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "gateway.md"
EXAMPLE = ROOT / "images" / "gateway" / "gateway.toml"
SECTIONS = ("ingest", "outbox", "zenoh", "estimator", "diagnosis", "clock")
"""The tables that may be left out altogether ([gateway] has required keys: only its optional
ones are left out in GOOD)."""


def _parts(cfg: GatewayConfig) -> dict[type, Any]:
    """Each settings dataclass → the object of it in a parsed config."""
    return {GatewayConfig: cfg, ZenohSettings: cfg.zenoh, Retry: cfg.zenoh.retry,
            EstimatorSettings: cfg.estimator, DiagnosisSettings: cfg.diagnosis,
            ClockSettings: cfg.clock}


@pytest.mark.parametrize("empty", [False, True], ids=["absent", "empty"])
def test_a_config_without_the_keys_parses_to_the_dataclass_defaults(empty: bool) -> None:
    raw = GOOD
    for name in SECTIONS if empty else ():
        raw = with_(name, {}, raw)
    for cls, got in _parts(parse_config(raw, "gw.toml")).items():
        for name, value in defaults(cls).items():
            assert getattr(got, name) == value, f"{cls.__name__}.{name}"


def _other(value: Any) -> Any:
    """A different value of the same type that the parser's own checks after reading accept
    (min_days <= days, retry_max_ms >= retry_initial_ms); None when there is none to try."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return 2.0 * value + 1.0
    if isinstance(value, str | tuple):
        return OTHER.get(value)
    return None


OTHER: dict[Any, Any] = {"info": "debug", "corrected": "adaptive", (15, 30, 60): (5, 20),
                         ("0.0.0.0", 5683): ("127.0.0.1", 5684)}
"""Other valid values for the defaults that are names or tuples."""


LEFT = {(ClockSettings, "scale"), (Retry, "factor")}
"""Not changed: the clock's scale (the parser also compares it with 1: another needs an epoch)
and the retry's growth factor (not a config key)."""


def test_a_default_changed_in_the_dataclass_is_what_the_parser_gives(monkeypatch) -> None:
    """The single source: every plain default is changed in the dataclass only, and a config
    without the keys gets the changed values (a literal left in the parser would not follow)."""
    changed: dict[tuple[type, str], Any] = {}
    for cls in _parts(parse_config(GOOD, "gw.toml")):
        for f in fields(cls):
            new = _other(f.default) if (cls, f.name) not in LEFT else None
            if new is not None:
                monkeypatch.setattr(f, "default", new)
                changed[(cls, f.name)] = new
    assert len(changed) >= 25  # nearly every default; the rest are None or factories
    parts = _parts(parse_config(GOOD, "gw.toml"))
    got = {k: getattr(parts[k[0]], k[1]) for k in changed}
    assert got == changed


def _doc_defaults() -> dict[tuple[str, str], str]:
    """docs/gateway.md's key table: (table, key) → the default cell, one per key (a row naming
    several keys gives their defaults comma-separated in the same order)."""
    text = DOC.read_text(encoding="utf-8")
    start = text.index("| table | key | default | meaning |")
    out: dict[tuple[str, str], str] = {}
    table = ""
    for line in text[start:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")][:3]
        table = cells[0].strip("`[]") or table
        keys = re.findall(r"`(\w+)`", cells[1])
        values = cells[2].split(", ") if len(keys) > 1 else [cells[2]]
        if len(values) == len(keys):
            out.update({(table, k): v for k, v in zip(keys, values, strict=True)})
    return out


def _toml_value(cell: str) -> Any:
    """A default cell as a TOML value (``3``, ``true``, `` `peer` ``, `` `[15, 30, 60]` ``);
    None for prose (``required``, ``none``, ``= inside``: nothing to set)."""
    inner = cell[1:-1] if cell.startswith("`") and cell.endswith("`") else cell
    if "`" in inner:
        return None
    try:
        return tomllib.loads(f"v = {inner}")["v"]
    except tomllib.TOMLDecodeError:
        return inner if inner != cell else None  # a bare word in backticks is a string


def _keys_read_with_a_default(monkeypatch) -> set[tuple[str, str]]:
    """(table, key) of every key the parser reads with a default other than None, outside the
    greenhouse tables (their defaults depend on the greenhouse: docs say so in words)."""
    seen: set[tuple[str, str]] = set()
    get = config_module._Table.get

    def spy(self, key, kind, default=config_module._REQUIRED, **kw):
        if default is not config_module._REQUIRED and default is not None:
            seen.add((self.path, key))
        return get(self, key, kind, default, **kw)

    monkeypatch.setattr(config_module._Table, "get", spy)
    parse_config(GOOD, "gw.toml")
    monkeypatch.undo()
    return {k for k in seen if not k[0].startswith("greenhouse[") and k != ("zenoh", "tls")}


def test_the_docs_state_the_defaults_the_parser_gives(monkeypatch) -> None:
    """Setting a key to the default docs/gateway.md states for it changes nothing; and every key
    the parser fills in has a row there with a value."""
    base = parse_config(GOOD, "gw.toml")
    checked, wrong = set(), []
    for (table, key), cell in _doc_defaults().items():
        value = _toml_value(cell)
        if value is None or table.startswith(("zenoh.tls", "location", "greenhouse")):
            continue
        checked.add((table, key))
        if parse_config(with_(f"{table}.{key}", value), "gw.toml") != base:
            wrong.append(f"[{table}] {key}: docs say {cell}")
    assert not wrong, wrong
    assert _keys_read_with_a_default(monkeypatch) <= checked


EXAMPLE_CHOICES = {("zenoh", "listen"), ("zenoh", "cache")}
"""What the shipped example sets on purpose to something else than the default: it listens for
subscribers on 7447, and keeps 16 samples per key for them (the default keeps 256)."""


def test_the_shipped_example_sets_the_defaults_unless_it_means_not_to() -> None:
    """A value the example writes out is what a deployment copied from it keeps when the
    dataclass default changes; so it must be the default, or a declared choice."""
    cfg = load_config(EXAMPLE)
    differ = {(part, f.name) for part, cls in (("zenoh", ZenohSettings), ("estimator", EstimatorSettings),
                                               ("diagnosis", DiagnosisSettings))
              for f in fields(cls) if getattr(getattr(cfg, part), f.name) != defaults(cls).get(f.name)}
    differ |= {("gateway", k) for k, v in defaults(GatewayConfig).items()
               if not hasattr(v, "__dataclass_fields__") and getattr(cfg, k) != v}
    assert differ == EXAMPLE_CHOICES

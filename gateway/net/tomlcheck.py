"""Small checks for TOML tables: every error names the file and the dotted key."""

from __future__ import annotations

import builtins
from collections.abc import Iterable
from pathlib import Path
from typing import Any


class ConfigError(ValueError):
    """A config that cannot be used; the message names the file and the key."""


class Table:
    """A TOML table read with its dotted location (``router.toml: tls.key``) for errors.

    (Below the methods ``str`` and ``bool`` the annotations name ``builtins.str``/``bool``.)"""

    def __init__(self, raw: Any, source: str, where: str = "") -> None:
        if not isinstance(raw, dict):
            raise ConfigError(f"{source}: '{where}' must be a table")
        self.raw, self.source, self.where = raw, source, where

    def _key(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def fail(self, key: str, message: str) -> ConfigError:
        return ConfigError(f"{self.source}: '{self._key(key)}' {message}")

    def only(self, allowed: Iterable[str]) -> None:
        allowed = sorted(allowed)
        for key in self.raw:
            if key not in allowed:
                raise ConfigError(f"{self.source}: unknown key '{self._key(key)}' "
                                  f"(allowed: {', '.join(allowed)})")

    def has(self, key: str) -> bool:
        return key in self.raw

    def table(self, key: str, default_empty: bool = True) -> Table:
        if key not in self.raw and default_empty:
            return Table({}, self.source, self._key(key))
        return Table(self.raw.get(key), self.source, self._key(key))

    def str(self, key: str, default: str | None = None, required: bool = False) -> str | None:
        if key not in self.raw:
            if required:
                raise self.fail(key, "is missing")
            return default
        value = self.raw[key]
        if not isinstance(value, str) or not value.strip():
            raise self.fail(key, f"must be a non-empty string, got {value!r}")
        return value

    def bool(self, key: builtins.str, default: bool) -> bool:
        value = self.raw.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false, got {value!r}")
        return value

    def strings(self, key: builtins.str,
                default: Iterable[builtins.str] = ()) -> tuple[builtins.str, ...]:
        value = self.raw.get(key, list(default))
        if not isinstance(value, list):
            raise self.fail(key, f"must be a list of strings, got {value!r}")
        for i, item in enumerate(value):
            if not isinstance(item, str) or not item.strip():
                raise ConfigError(f"{self.source}: '{self._key(key)}[{i}]' must be a non-empty "
                                  f"string, got {item!r}")
        return tuple(value)

    def path(self, key: builtins.str, base: Path, required: builtins.bool = False) -> Path | None:
        """A file path; a relative one is taken from the config file's folder."""
        text = self.str(key, required=required)
        if text is None:
            return None
        p = Path(text).expanduser()
        return p if p.is_absolute() else base / p

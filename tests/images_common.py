"""What the ``make images`` tests share besides the ``bundles`` fixture (tests/conftest.py):
images/build.py loaded as a module, and a systemd unit read as a dict."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from tests.mcu_fakes.hostenv import ROOT

_spec = importlib.util.spec_from_file_location("serra_images_build", ROOT / "images" / "build.py")
assert _spec and _spec.loader
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)


def read_unit(path: Path) -> dict[str, list[str]]:
    """systemd unit → {key: [values]} over all sections (keys may repeat; \\ continues a line)."""
    text = path.read_text(encoding="utf-8").replace("\\\n", " ")
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            out.setdefault(key.strip(), []).append(" ".join(value.split()))
    return out

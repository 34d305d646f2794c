"""onnxruntime, imported with its telemetry off.

onnxruntime's Linux wheels (1.29 on; 1.32 here) send usage events to Microsoft's 1DS collector
(``mobile.events.data.microsoft.com``, ``core/platform/posix/telemetry_1ds.cc``) and keep a
device id and an event store in ``~/.cache/Microsoft/DeveloperTools/.onnxruntime`` unless
``ORT_DISABLE_TELEMETRY`` is set when the library is imported: set later it changes nothing
(checked with 1.32: the store is written after an import made first). A gateway on a farm's link
sends nothing it was not asked to, so every import of onnxruntime in the project goes through
:func:`load`; a value the user set is kept.
"""

from __future__ import annotations

import os
from types import ModuleType

TELEMETRY_ENV = "ORT_DISABLE_TELEMETRY"


def telemetry_off() -> None:
    """Set ``ORT_DISABLE_TELEMETRY=1`` in this process's environment (and its children's) unless
    it is set already: before anything imports onnxruntime (test and bench runners call it)."""
    os.environ.setdefault(TELEMETRY_ENV, "1")


def load() -> ModuleType:
    """The ``onnxruntime`` module, its telemetry off unless the environment says otherwise."""
    telemetry_off()
    import onnxruntime

    return onnxruntime

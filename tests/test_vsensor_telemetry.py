"""onnxruntime's telemetry stays off wherever the project loads it (gateway/vsensor/ort.py).

onnxruntime 1.32's Linux wheel keeps a device id and an event store under
``~/.cache/Microsoft/DeveloperTools/.onnxruntime`` for the events it sends to Microsoft unless
``ORT_DISABLE_TELEMETRY`` is set at its import: that store is what these tests look for, in a
HOME of their own, in fresh interpreters started without the variable.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "gateway" / "vsensor" / "models" / "almeria.onnx"
STORE = Path(".cache") / "Microsoft" / "DeveloperTools" / ".onnxruntime"

BARE = f"""
import onnxruntime as ort
ort.InferenceSession({str(MODEL)!r}, providers=["CPUExecutionProvider"])
"""

GATEWAY = f"""
from gateway.greenhouse import load_greenhouse
from gateway.vsensor import VentSensor
VentSensor({str(MODEL)!r}, load_greenhouse("almeria-palmerillas"), None)
"""


def _run(code: str, home: Path, **extra: str) -> Path:
    env = {k: v for k, v in os.environ.items() if k != "ORT_DISABLE_TELEMETRY"}
    env.update(HOME=str(home), PYTHONPATH=str(ROOT), XDG_CACHE_HOME=str(home / ".cache"), **extra)
    subprocess.run([sys.executable, "-c", code], env=env, cwd=home, check=True, timeout=120,
                   stdout=subprocess.DEVNULL)
    return home / STORE


@pytest.fixture
def keeps_a_store(tmp_path: Path) -> None:
    """Skip when this onnxruntime keeps no telemetry store at all (nothing to hold off)."""
    home = tmp_path / "bare"
    home.mkdir()
    if not _run(BARE, home).exists():
        pytest.skip("this onnxruntime writes no telemetry store: nothing to check")


def test_the_gateway_loads_its_sensor_with_onnxruntime_telemetry_off(tmp_path, keeps_a_store):
    home = tmp_path / "gateway"
    home.mkdir()
    assert not _run(GATEWAY, home).exists()


def test_a_user_who_sets_the_variable_keeps_their_value(tmp_path, keeps_a_store):
    home = tmp_path / "opted-in"
    home.mkdir()
    code = GATEWAY + "import os; assert os.environ['ORT_DISABLE_TELEMETRY'] == '0'\n"
    _run(code, home, ORT_DISABLE_TELEMETRY="0")


def test_the_project_imports_onnxruntime_only_through_its_loader():
    import ast

    direct = []
    for path in sorted([*(ROOT / "gateway").rglob("*.py"), *(ROOT / "training").rglob("*.py")]):
        if path == ROOT / "gateway" / "vsensor" / "ort.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n.split(".")[0] == "onnxruntime" for n in names):
                direct.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not direct, f"import onnxruntime through gateway.vsensor.ort.load(): {direct}"

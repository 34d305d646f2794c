"""Import direction: the gateway (what the wheel ships) never imports the offline tools."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = ("training", "tests", "images")  # repository folders the wheel does not carry


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every absolute import in a file, wherever it sits (functions too)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant)):
            found.append((node.lineno, str(node.args[0].value)))
    return found


def test_gateway_imports_nothing_from_the_repository_tools() -> None:
    files = sorted((ROOT / "gateway").rglob("*.py"))
    assert len(files) > 30  # the scan sees the package
    bad = [f"{f.relative_to(ROOT)}:{line}: imports {mod}"
           for f in files for line, mod in imported_modules(f)
           if mod.split(".")[0] in FORBIDDEN]
    assert not bad, "\n".join(bad)


def test_the_scan_finds_an_import_inside_a_function(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text("def f():\n    from training.simulate import simulate\n"
                   "import importlib\nimportlib.import_module('training.demo')\n")
    assert sorted(imported_modules(src)) == [(2, "training.simulate"), (3, "importlib"),
                                             (4, "training.demo")]

"""The repository stands alone: every doc that code or docs cite exists, none points at ../shared."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "images").rglob("*.md"),
           *(ROOT / "gateway").rglob("*.py"), *(ROOT / "training").rglob("*.py"),
           *(ROOT / "mcu").glob("*.py")]


def test_cited_docs_exist_and_nothing_cites_the_shared_notes() -> None:
    assert len(SOURCES) > 50
    bad = []
    for path in SOURCES:
        text = path.read_text(encoding="utf-8")
        for m in re.finditer(r"\bdocs/([\w.-]+\.md)", text):
            if not (ROOT / "docs" / m[1]).exists():
                bad.append(f"{path.relative_to(ROOT)}: cites missing docs/{m[1]}")
        for old in ("../shared", "MODEL_NOTES", "ARCHITECTURE.md", "DATA_FORMAT.md"):
            if old in text:
                bad.append(f"{path.relative_to(ROOT)}: cites {old} (now in docs/)")
    assert not bad, "\n".join(bad)

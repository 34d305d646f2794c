"""A section that code or docs cite by title exists in the doc they name.

Citations read ``docs/effects.md, "Sky temperature"`` (or ``effects.md "…"`` inside docs/): the
title must begin a heading or a bold paragraph lead of that file, so moving or renaming a section
cannot leave a reader, or a docstring, pointing at nothing."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "images").rglob("*.md"),
           *(ROOT / "gateway").rglob("*.py"), *(ROOT / "training").rglob("*.py"),
           *(ROOT / "mcu").glob("*.py"), *(ROOT / "tests").rglob("*.py")]
CITATION = re.compile(
    r"\b((?:docs/)?[\w-]+\.md)\)?,?\s*(?:section\s+)?[\"“]([A-Za-z][^\"”\n]{2,100})[\"”]")
"""A file name, an optional comma or "section", then a quoted title starting with a letter."""


def anchors(text: str) -> list[str]:
    """The headings and bold paragraph leads of a Markdown text, lower case, without backticks."""
    found = [re.sub(r"^#+\s*", "", line) for line in text.splitlines() if line.startswith("#")]
    found += re.findall(r"\*\*([^*]{3,160})\*\*", text)
    return [a.replace("`", "").strip().lower() for a in found]


def unresolved(sources: list[Path], docs: dict[str, list[str]], root: Path = ROOT) -> list[str]:
    """``path:line: file "title"`` for every citation of a known doc whose title begins nothing."""
    bad = []
    for path in sources:
        text = path.read_text(encoding="utf-8")
        for m in CITATION.finditer(text):
            name = m[1].removeprefix("docs/")
            if name not in docs:
                continue
            title = m[2].replace("`", "").strip().rstrip(".,").lower()
            if not any(a.startswith(title) for a in docs[name]):
                line = text.count("\n", 0, m.start()) + 1
                bad.append(f'{path.relative_to(root)}:{line}: {m[1]} "{m[2]}"')
    return bad


def test_every_cited_section_exists() -> None:
    docs = {p.name: anchors(p.read_text(encoding="utf-8")) for p in (ROOT / "docs").glob("*.md")}
    docs["README.md"] = anchors((ROOT / "README.md").read_text(encoding="utf-8"))
    assert len(docs) > 10 and len(SOURCES) > 100
    bad = unresolved(SOURCES, docs)
    assert not bad, "cited sections that do not exist:\n" + "\n".join(bad)


def test_a_renamed_section_is_caught(tmp_path: Path) -> None:
    src = tmp_path / "mod.py"
    src.write_text('"""See docs/notes.md, "Old title", and docs/notes.md "Kept".\nnotes.md "Lead"')
    docs = {"notes.md": anchors("# Kept heading\n\ntext **Lead in bold.** more\n## New title\n")}
    assert unresolved([src], docs, tmp_path) == ['mod.py:1: docs/notes.md "Old title"']

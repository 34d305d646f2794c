"""The repository stands alone: every doc that code or docs cite exists, none points at ../shared,
no tracked file cites the development machine's notes folder, and the docs' relative links
resolve."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "images").rglob("*.md"),
           *(ROOT / "gateway").rglob("*.py"), *(ROOT / "training").rglob("*.py"),
           *(ROOT / "mcu").glob("*.py")]
NOTES = "/".join(("", "work", "notes"))
"""The lead's notes folder on the development machine (built so this file does not cite it):
a clean clone has none of it, so a doc or docstring must state what it relies on."""
UNTRACKED = {".venv", "out", "build", "dist", "node_modules"}
"""Top-level folders of a working tree that are never tracked (scratch, environments)."""
LINK = re.compile(r"\]\(([^)\s]+)")
"""The target of a Markdown inline link, up to its closing parenthesis or a title."""


def tracked_text(root: Path = ROOT) -> list[Path]:
    """The .md and .py files git tracks; without git (an exported tree) every one outside the
    untracked and hidden folders."""
    try:
        out = subprocess.run(["git", "-C", str(root), "ls-files", "-z", "--", "*.md", "*.py"],
                             capture_output=True, check=True).stdout
        return [root / name for name in out.decode("utf-8").split("\0") if name]
    except (OSError, subprocess.CalledProcessError):
        return [p for ext in ("*.md", "*.py") for p in root.rglob(ext)
                if not (set(p.relative_to(root).parts[:1]) & UNTRACKED
                        or any(part.startswith(".") for part in p.relative_to(root).parts))]


def notes_citations(paths: list[Path], root: Path = ROOT) -> list[str]:
    """``path:line`` of every mention of the notes folder."""
    bad = []
    for path in paths:
        text = path.read_text(encoding="utf-8", errors="replace")
        for m in re.finditer(re.escape(NOTES), text):
            line = text.count("\n", 0, m.start()) + 1
            bad.append(f"{path.relative_to(root)}:{line}: cites {NOTES}")
    return bad


def broken_links(paths: list[Path], root: Path = ROOT) -> list[str]:
    """``path:line: target`` of every relative Markdown link whose file does not exist (URLs,
    mail and in-page anchors are not checked)."""
    bad = []
    for path in paths:
        text = path.read_text(encoding="utf-8")
        for m in LINK.finditer(text):
            target = m[1].strip("<>")
            if "://" in target or target.startswith(("#", "mailto:")):
                continue
            if not (path.parent / target.split("#", 1)[0]).exists():
                line = text.count("\n", 0, m.start()) + 1
                bad.append(f"{path.relative_to(root)}:{line}: links to missing {target}")
    return bad


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


def test_no_tracked_file_cites_the_notes_folder() -> None:
    paths = tracked_text()
    assert len(paths) > 300 and Path(__file__).resolve() in {p.resolve() for p in paths}
    bad = notes_citations(paths)
    assert not bad, "\n".join(bad)


def test_the_docs_relative_links_resolve() -> None:
    docs = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "images").rglob("*.md")]
    assert sum(len(LINK.findall(p.read_text(encoding="utf-8"))) for p in docs) > 20
    bad = broken_links(docs)
    assert not bad, "\n".join(bad)


def test_the_checks_catch_a_notes_citation_and_a_broken_link(tmp_path: Path) -> None:
    doc = tmp_path / "docs" / "a.md"
    doc.parent.mkdir()
    (tmp_path / "docs" / "b.md").write_text("# B\n", encoding="utf-8")
    doc.write_text(f"rule ({NOTES}/x-rule.txt)\n[b](b.md#b) [c](c.md) [w](https://x.org/c.md)\n",
                   encoding="utf-8")
    assert notes_citations([doc], tmp_path) == [f"docs/a.md:1: cites {NOTES}"]
    assert broken_links([doc], tmp_path) == ["docs/a.md:2: links to missing c.md"]

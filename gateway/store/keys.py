"""Per-device HMAC keys, read from a file that must not be readable by other users.

Format, one device a line (blank lines and `#` comments allowed):
    <device_id> <key as 32..128 hex digits> [name]
"""

from __future__ import annotations

import os
import stat
from pathlib import Path


class KeyFileError(ValueError):
    pass


def check_permissions(path: Path) -> None:
    mode = stat.S_IMODE(os.stat(path).st_mode)
    if mode & 0o027:
        raise KeyFileError(
            f"{path}: keys file mode is {mode:04o}; it must not be readable or writable by other "
            f"users nor writable by the group (run: chmod 600 {path})")


def parse_keys(text: str, where: str = "<keys>") -> dict[int, bytes]:
    keys: dict[int, bytes] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) < 2:
            raise KeyFileError(f"{where}:{n}: expected '<device_id> <hex key> [name]'")
        try:
            dev = int(parts[0], 0)
        except ValueError:
            raise KeyFileError(f"{where}:{n}: device id {parts[0]!r} is not an integer") from None
        if not 0 <= dev <= 0xFFFFFFFF:
            raise KeyFileError(f"{where}:{n}: device id {dev} outside 0..4294967295")
        try:
            key = bytes.fromhex(parts[1])
        except ValueError:
            raise KeyFileError(f"{where}:{n}: key of device {dev} is not hexadecimal") from None
        if not 16 <= len(key) <= 64:
            raise KeyFileError(f"{where}:{n}: key of device {dev} has {len(key)} bytes, "
                               "expected 16 to 64 (32 recommended)")
        if dev in keys:
            raise KeyFileError(f"{where}:{n}: device {dev} listed twice")
        keys[dev] = key
    return keys


def load_keys(path: str | Path) -> dict[int, bytes]:
    path = Path(path)
    check_permissions(path)
    return parse_keys(path.read_text(encoding="utf-8"), str(path))


def write_keys(path: str | Path, keys: dict[int, bytes]) -> None:
    """Write a keys file with mode 0600 (used by provisioning and tests)."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.fchmod(fd, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        for dev, key in sorted(keys.items()):
            f.write(f"{dev} {key.hex()}\n")

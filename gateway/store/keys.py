"""Per-device HMAC keys, read from a file that must not be readable by other users.

Format, one device a line (blank lines and `#` comments allowed):
    <device_id> <key as 32..128 hex digits> [name]

Made and changed with ``python -m gateway keys add|rotate`` (gateway/cli/keys.py), which edit
the file in place through `set_key` (atomic rename, mode and owner kept, 0600 when new).
"""

from __future__ import annotations

import contextlib
import hmac
import os
import secrets
import stat
from dataclasses import dataclass
from pathlib import Path


class KeyFileError(ValueError):
    pass


def key_id(key: bytes) -> str:
    """A short public name for a key (12 hex digits): tells keys apart, reveals nothing of them."""
    return hmac.digest(key, b"serra key id", "sha256")[:6].hex()


def is_weak(key: bytes) -> bool:
    """The published example key (00 01 02 ...) or one byte repeated (all zero, all FF)."""
    return key == bytes(range(len(key))) or len(set(key)) == 1


def new_key(nbytes: int = 32) -> bytes:
    return secrets.token_bytes(nbytes)


def _hint(dev: int, path: str) -> str:
    return f"make a real one with: python -m gateway keys rotate {dev} --keys {path}"


def check_permissions(path: Path) -> None:
    st = os.stat(path)
    if stat.S_ISDIR(st.st_mode):
        raise KeyFileError(f"{path}: is a directory, not a keys file")
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError(f"{path}: not a regular file")
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o027:
        raise KeyFileError(
            f"{path}: keys file mode is {mode:04o}; it must not be readable or writable by other "
            f"users nor writable by the group (run: chmod 600 {path})")


@dataclass(frozen=True)
class KeyLine:
    """One device line of a keys file, as written."""

    line: int  # 1-based
    device_id: int
    key: bytes
    name: str


def parse_lines(text: str, where: str = "<keys>") -> list[KeyLine]:
    """Every device line, checked for syntax and duplicates (not for weak keys)."""
    out: list[KeyLine] = []
    seen: set[int] = set()
    for n, line in enumerate(text.splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
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
        if dev in seen:
            raise KeyFileError(f"{where}:{n}: device {dev} listed twice")
        seen.add(dev)
        out.append(KeyLine(n, dev, key, " ".join(parts[2:])))
    return out


def parse_keys(text: str, where: str = "<keys>") -> dict[int, bytes]:
    keys: dict[int, bytes] = {}
    for k in parse_lines(text, where):
        if is_weak(k.key):
            what = ("the published example key" if k.key == bytes(range(len(k.key)))
                    else "a key of one repeated byte")
            raise KeyFileError(f"{where}:{k.line}: device {k.device_id} has {what}, which anyone "
                               f"can forge packets with; {_hint(k.device_id, where)}")
        keys[k.device_id] = k.key
    return keys


def read_text(path: str | Path) -> str:
    """The file as text; a byte that is not UTF-8 is named by file and line."""
    path = Path(path)
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise KeyFileError(f"{path}:{line}: not UTF-8 text (byte 0x{data[e.start]:02x}); "
                           "a keys file holds ASCII ids, hex keys and names") from None


def load_keys(path: str | Path) -> dict[int, bytes]:
    path = Path(path)
    check_permissions(path)
    return parse_keys(read_text(path), str(path))


def write_keys(path: str | Path, keys: dict[int, bytes]) -> None:
    """Write a keys file with mode 0600 (used by provisioning and tests)."""
    _replace(Path(path), "".join(f"{dev} {key.hex()}\n" for dev, key in sorted(keys.items())))


@dataclass(frozen=True)
class KeyChange:
    """What `set_key` did: the new key and the one it replaced (None for a new device)."""

    device_id: int
    key: bytes
    old: bytes | None
    created_file: bool


def set_key(path: str | Path, device_id: int, key: bytes, *, name: str | None = None,
            rotate: bool = False) -> KeyChange:
    """Add a device (rotate=False: refused if it has a key) or give it a new key (rotate=True:
    refused if it has none). Other lines, comments and the file's mode and owner are kept."""
    path = Path(path)
    if path.is_symlink():  # edit the file the link points to, keep the link
        path = path.resolve()
    if not path.parent.is_dir():
        raise KeyFileError(f"{path}: no such directory {path.parent}")
    exists = path.exists()
    text = ""
    if exists:
        check_permissions(path)
        text = read_text(path)
    lines = {k.device_id: k for k in parse_lines(text, str(path))}
    old = lines.get(device_id)
    if old is not None and not rotate:
        raise KeyFileError(
            f"{path}: device {device_id} already has a key (key id {key_id(old.key)}); to give "
            f"it a new one (a reflashed or replaced board): python -m gateway keys rotate "
            f"{device_id} --keys {path}")
    if old is None and rotate:
        what = (f"no device {device_id} in the file" if exists
                else f"no such keys file, so no device {device_id} to rotate")
        raise KeyFileError(f"{path}: {what}; add it with: "
                           f"python -m gateway keys add {device_id} --keys {path}")
    label = old.name if old is not None and name is None else (name or "")
    entry = f"{device_id} {key.hex()}" + (f" {label}" if label else "")
    rows = text.splitlines()
    if old is not None:
        comment = rows[old.line - 1].partition("#")[2]
        rows[old.line - 1] = entry + (f"  #{comment}" if comment else "")
    else:
        rows.append(entry)
    _replace(path, "\n".join(rows) + "\n")
    return KeyChange(device_id, key, None if old is None else old.key, not exists)


def _replace(path: Path, text: str) -> None:
    """Write `text` to a new file beside `path` and rename it over: a crash leaves the old file
    or the new one, never half of one. Created 0600; an existing file's mode and owner are kept
    (root editing the service's file must not leave it unreadable to the service)."""
    try:
        st: os.stat_result | None = os.stat(path)
    except FileNotFoundError:
        st = None
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        if st is not None:
            with contextlib.suppress(PermissionError):
                os.fchown(fd, st.st_uid, st.st_gid)
        os.fchmod(fd, 0o600 if st is None else stat.S_IMODE(st.st_mode) & ~0o027)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            fd = -1
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if fd >= 0:
            os.close(fd)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)

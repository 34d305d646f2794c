"""Boot counter in flash: sequence numbers restart at 0 each boot, so (boot, seq) never repeats.

Two copies, each written to a temporary file then renamed (atomic on LittleFS), the primary
first. If one copy is corrupted, the other is at most one boot behind it, so skipping one value
keeps boots unique. A missing copy beside a corrupted one bounds nothing (it may have been
deleted, or never written while the primary counted on): then, as when both are corrupted, the
board does not start, because a repeated boot restarts seq at 0 and the gateway would take its
records for duplicates of stored ones and store nothing.
"""

import os


class BootCountError(Exception):
    pass


def _read(path: str):
    """-1 if absent, None if corrupted, else the stored count."""
    try:
        with open(path) as f:
            text = f.read()
    except OSError:
        return -1
    parts = text.split()
    # "boot <n> <n xor 0x5a5a5a5a>": the check value catches a corrupted flash page.
    try:
        if len(parts) == 3 and parts[0] == "boot":
            n = int(parts[1])
            if n >= 0 and n ^ 0x5A5A5A5A == int(parts[2]):
                return n
    except ValueError:
        pass
    return None


def _write(path: str, n: int) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(f"boot {n} {n ^ 0x5A5A5A5A}\n")
    os.rename(tmp, path)


def next_boot(path: str = "boot.cnt") -> int:
    """Increment and persist the counter before anything is sent; returns the new value."""
    a, b = _read(path), _read(path + ".bak")
    if a is None or b is None:
        good = b if a is None else a
        if good is None or good < 0:
            state = (f"{path} and {path}.bak both corrupted" if good is None else
                     f"{path}{'' if a is None else '.bak'} corrupted, the other copy missing")
            raise BootCountError(f"{state}: cannot guarantee unique boots; as for a reflashed "
                                 f"board, delete {path} and {path}.bak and run `python -m gateway "
                                 "keys rotate <device>` (docs/wire-format.md)")
        n = good + 1  # the lost copy was at most this
    else:
        n = a if a > b else b
    n += 1
    _write(path, n)
    _write(path + ".bak", n)
    return n

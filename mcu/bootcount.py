"""Boot counter in flash: sequence numbers restart at 0 each boot, so (boot, seq) never repeats.

Two copies, each written to a temporary file then renamed (atomic on LittleFS). If one copy is
corrupted, the other is at most one boot behind it, so skipping one value keeps boots unique.
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
    if a is None and b is None:
        raise BootCountError(f"{path} and {path}.bak both corrupted: cannot guarantee unique sequence "
                             "numbers; provision a new counter")
    if a is None or b is None:
        n = (b if a is None else a) + 1  # the lost copy was at most this
    else:
        n = a if a > b else b
    n += 1
    _write(path, n)
    _write(path + ".bak", n)
    return n

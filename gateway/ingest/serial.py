"""Serial transport (board on USB): COBS frames over pyserial, read in a thread."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Hashable

import serial  # pyserial

from gateway.ingest.core import IngestCore
from gateway.ingest.framing import Deframer, FramingError, cobs_encode


class SerialTransport:
    def __init__(self, core: IngestCore, url: str, baudrate: int = 115200) -> None:
        self.core = core
        self.url = url
        self.port = serial.serial_for_url(url, baudrate=baudrate, timeout=0.1)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wlock = threading.Lock()

    def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._thread = threading.Thread(target=self._reader, args=(loop,), daemon=True,
                                        name="serra-serial")
        self._thread.start()

    def _send(self, pkt: bytes, peer: Hashable) -> None:
        with self._wlock:
            self.port.write(cobs_encode(pkt) + b"\0")

    def _reader(self, loop: asyncio.AbstractEventLoop) -> None:
        deframer = Deframer()
        while not self._stop.is_set():
            try:
                data = self.port.read(max(1, self.port.in_waiting))
            except (serial.SerialException, OSError) as e:
                self.core.rlog.warning("serial_error", "serial %s: %s", self.url, e)
                self.core.counters["serial_error"] += 1
                self._stop.wait(1.0)
                continue
            if not data:
                continue
            for frame in deframer.feed(data):
                if isinstance(frame, FramingError):
                    loop.call_soon_threadsafe(self._framing_error, frame)
                else:
                    loop.call_soon_threadsafe(self.core.handle, frame, self.url, self._send)

    def _framing_error(self, e: FramingError) -> None:
        self.core.counters["framing"] += 1
        self.core.rlog.warning("framing", "serial %s: bad frame: %s", self.url, e)

    def pause(self) -> None:
        """Take no more frames (a shutdown): the port stays open for the final drain's acks."""
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=2)

    def close(self) -> None:
        self.pause()
        self.port.close()

"""A TCP relay on 127.0.0.1 whose link can be cut and restored (Zenoh link-cut tests).

While cut, every relayed connection is closed and new ones are accepted then closed at once, so
the port stays ours and the peer's reconnect attempts fail fast until ``restore()``.
"""

from __future__ import annotations

import select
import socket
import threading


class TcpCut:
    def __init__(self, target_port: int, host: str = "127.0.0.1") -> None:
        self.target = (host, target_port)
        self.lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.lsock.bind((host, 0))
        self.lsock.listen(16)
        self.port = self.lsock.getsockname()[1]
        self.endpoint = f"tcp/{host}:{self.port}"
        self._lock = threading.Lock()
        self._pairs: list[tuple[socket.socket, socket.socket]] = []
        self._cut = False
        self._stop = False
        self.accepted = 0
        self._thread = threading.Thread(target=self._run, daemon=True, name="tcpcut")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop:
            with self._lock:
                socks = [self.lsock] + [s for pair in self._pairs for s in pair]
            try:
                ready, _, _ = select.select(socks, [], [], 0.05)
            except (OSError, ValueError):
                continue  # a socket was closed by cut(): rebuild the list
            for s in ready:
                if s is self.lsock:
                    self._accept()
                else:
                    self._relay(s)

    def _accept(self) -> None:
        try:
            c, _ = self.lsock.accept()
        except OSError:
            return
        if self._cut:
            c.close()
            return
        try:
            up = socket.create_connection(self.target, timeout=5)
        except OSError:
            c.close()
            return
        self.accepted += 1
        with self._lock:
            self._pairs.append((c, up))

    def _relay(self, s: socket.socket) -> None:
        with self._lock:
            pair = next((p for p in self._pairs if s in p), None)
        if pair is None:
            return
        other = pair[1] if s is pair[0] else pair[0]
        try:
            data = s.recv(65536)
            if data:
                other.sendall(data)
                return
        except OSError:
            pass
        self._close(pair)

    def _close(self, pair: tuple[socket.socket, socket.socket]) -> None:
        with self._lock:
            if pair in self._pairs:
                self._pairs.remove(pair)
        for s in pair:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def cut(self) -> None:
        self._cut = True
        with self._lock:
            pairs = list(self._pairs)
        for p in pairs:
            self._close(p)

    def restore(self) -> None:
        self._cut = False

    def close(self) -> None:
        self._stop = True
        self.cut()
        self._thread.join(timeout=5)
        self.lsock.close()

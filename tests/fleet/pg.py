"""A throwaway PostgreSQL cluster in a temporary folder, for tests and benches (no mock).

    with PgCluster() as pg:          # initdb + pg_ctl start (~2 s); stopped and removed after
        store = PgStore.connect(pg.dsn, schema="t1")
        pg.stop_server(); pg.start_server()   # the database down, then back (same data, port)

It listens on a Unix socket in its own folder only (no TCP port, so nothing to collide with)
and, when asked, on 127.0.0.1 at a port the OS chose. ``initdb`` refuses to run as root: as root
the cluster runs as the ``postgres`` user (``runuser -u postgres --``), owning the folder.
"""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

TIMEOUT = 180  # [s] initdb and start on a loaded 2-core machine


def available() -> str | None:
    """None if a cluster can be made here, else why not."""
    for tool in ("initdb", "pg_ctl"):
        if shutil.which(tool) is None:
            return f"{tool} is not on PATH (PostgreSQL server binaries)"
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            return "running as root and there is no 'postgres' user to run initdb as"
        if shutil.which("runuser") is None:
            return "running as root and runuser is missing"
    return None


class PgCluster:
    def __init__(self, tcp: bool = False) -> None:
        self.tcp = tcp
        self.folder: Path | None = None
        self.port = 5432  # names the socket file only, unless tcp
        self.running = False

    @property
    def data(self) -> Path:
        assert self.folder is not None
        return self.folder / "data"

    @property
    def dsn(self) -> str:
        """Unix-socket DSN of the ``postgres`` database as the superuser ``postgres``."""
        return f"host={self.folder} port={self.port} user=postgres dbname=postgres"

    @property
    def tcp_dsn(self) -> str:
        assert self.tcp, "start the cluster with tcp=True"
        return f"host=127.0.0.1 port={self.port} user=postgres dbname=postgres"

    def _run(self, *args: str) -> subprocess.CompletedProcess[str]:
        cmd = list(args)
        if os.geteuid() == 0:
            cmd = ["runuser", "-u", "postgres", "--", *cmd]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT, check=False)

    def start(self) -> PgCluster:
        self.folder = Path(tempfile.mkdtemp(prefix="serra-pg-"))
        if os.geteuid() == 0:
            pw = pwd.getpwnam("postgres")
            os.chown(self.folder, pw.pw_uid, pw.pw_gid)
        r = self._run("initdb", "-D", str(self.data), "-A", "trust", "-U", "postgres", "-E", "UTF8",
                      "--locale=C", "--no-sync")
        if r.returncode != 0:
            raise RuntimeError(f"initdb failed: {r.stderr.strip()[-1500:]}")
        if self.tcp:
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                self.port = s.getsockname()[1]
        return self.start_server()

    def start_server(self) -> PgCluster:
        """Start the server on the cluster made by start() (again after stop_server())."""
        assert self.folder is not None
        options = (f"-k {self.folder} -p {self.port} "
                   f"-c listen_addresses={'127.0.0.1' if self.tcp else chr(39) * 2} "
                   "-c fsync=off -c synchronous_commit=off -c full_page_writes=off")
        r = self._run("pg_ctl", "-D", str(self.data), "-o", options, "-l", str(self.folder / "log"),
                      "-w", "-t", str(TIMEOUT), "start")
        if r.returncode != 0:
            log = (self.folder / "log").read_text(errors="replace")[-1500:] if (
                self.folder / "log").exists() else ""
            self.stop()
            raise RuntimeError(f"pg_ctl start failed: {r.stderr.strip()} {log}")
        self.running = True
        return self

    def stop_server(self) -> None:
        """Stop the server, keeping the cluster (a database that goes down: start_server())."""
        r = self._run("pg_ctl", "-D", str(self.data), "-m", "fast", "-w", "-t", str(TIMEOUT), "stop")
        if r.returncode != 0:
            raise RuntimeError(f"pg_ctl stop failed: {r.stderr.strip()}")
        self.running = False

    def stop(self) -> None:
        """Stop the server (immediate: a throwaway cluster) and remove its folder."""
        if self.folder is None:
            return
        if self.running or (self.data / "postmaster.pid").exists():
            self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "-t", str(TIMEOUT), "stop")
            self.running = False
        shutil.rmtree(self.folder, ignore_errors=True)
        self.folder = None

    def __enter__(self) -> PgCluster:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

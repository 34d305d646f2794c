"""The gateway's work folder (gateway/service/workdir.py): a stop on SIGTERM or SIGINT removes it,
even while the diagnosis subprocess reads from it; a killed gateway's stays until a later
gateway starts in the same temporary folder, which removes it and nothing else: not a running
gateway's, not a folder without the lock file, not another tool's ``serra-…`` folder, not one
of another user or behind a link."""

from __future__ import annotations

import fcntl
import os
import signal
import tempfile
import time
from pathlib import Path

import pytest

from gateway.service.workdir import LOCK, PREFIX, sweep_stale, work_folder
from gateway.store import Store
from tests.gateway_harness import EPOCH, GatewayProcess, shifted_kit, wait_for, write_config
from tests.test_gateway_diagnosis import copy_store


def work_folders(tmp: Path) -> set[Path]:
    return set(tmp.glob(f"{PREFIX}*"))


def others(tmp: Path) -> set[Path]:
    """What a gateway must leave alone in ``tmp``: other tools' folders of the project (a free
    lock file of the gateway's name in them: only the prefix tells), and one named as a
    gateway's without the lock file."""
    made = {tmp / "serra-vsensor-0f3a", tmp / "serra-bench-soak-x1", tmp / f"{PREFIX}no-lock"}
    for d in made:
        d.mkdir()
        (d / "data").write_text("kept")
        if not d.name.startswith(PREFIX):
            (d / LOCK).write_text("")
    return made


def gateway_in(folder: Path, name: str) -> GatewayProcess:
    """Gateway ``name`` (its config, store and keys ``name``.*) in ``folder``, its $TMPDIR
    (GatewayProcess's: the config's folder), shared by every gateway of the test, as is the log
    gateway.log."""
    toml = write_config(folder, anchor=time.time())
    (folder / "keys.txt").rename(folder / f"{name}.keys")
    toml.rename(folder / f"{name}.toml")
    text = (folder / f"{name}.toml").read_text()
    (folder / f"{name}.toml").write_text(text.replace('db = "gw.db"', f'db = "{name}.db"')
                                         .replace('keys = "keys.txt"', f'keys = "{name}.keys"'))
    return GatewayProcess(folder / f"{name}.toml")


def test_a_killed_gateways_work_folder_goes_when_the_next_one_starts(tmp_path: Path) -> None:
    kept = others(tmp_path)
    gws = {name: gateway_in(tmp_path, name) for name in ("running", "killed", "next")}
    try:
        gws["running"].start()
        (running,) = work_folders(tmp_path) - kept
        gws["killed"].start()
        (killed,) = work_folders(tmp_path) - kept - {running}
        gws["killed"].kill()  # SIGKILL: nothing of it runs to remove its folder
        assert killed.is_dir()
        gws["next"].start()  # its sweep runs before it is ready (the running one's ran before
        assert not killed.exists()  # the killed one was there)
        (new,) = work_folders(tmp_path) - kept - {running}
        assert running.is_dir() and all((d / "data").read_text() == "kept" for d in kept)
        assert gws["running"].stop() == 0 and gws["next"].stop() == 0
    finally:
        for gw in gws.values():
            gw.kill()
    assert set(tmp_path.glob("serra-*")) == kept  # each stopped gateway removed its own
    log = (tmp_path / "gateway.log").read_text()
    assert log.count("removed the work folder") == 1, log
    assert f"removed the work folder(s) of gateways that were killed: {killed}" in log


def dead_gateways_folder(tmp: Path, name: str) -> Path:
    """A folder as a killed gateway leaves it: its lock file, locked by nobody."""
    d = tmp / name
    d.mkdir()
    (d / LOCK).write_text("")
    (d / "diagnosis-north.csv").write_text("t\n")
    return d


def test_the_sweep_takes_only_what_is_clearly_a_dead_gateways(tmp_path: Path) -> None:
    kept = others(tmp_path)
    dead = dead_gateways_folder(tmp_path, f"{PREFIX}dead")
    target = dead_gateways_folder(tmp_path, "elsewhere")  # a dead one's, but reached by a link
    (tmp_path / f"{PREFIX}link").symlink_to(target)
    kept |= {tmp_path / f"{PREFIX}link", target}
    linked = tmp_path / f"{PREFIX}linked-lock"  # its lock file a link to a free lock
    linked.mkdir()
    (linked / LOCK).symlink_to(target / LOCK)
    kept.add(linked)
    if os.geteuid() == 0:  # root can make one of another user's
        theirs = dead_gateways_folder(tmp_path, f"{PREFIX}theirs")
        os.chown(theirs, 4242, 4242)
        kept.add(theirs)
    held = dead_gateways_folder(tmp_path, f"{PREFIX}held")  # its gateway runs: lock held
    fd = os.open(held / LOCK, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        assert sweep_stale(tmp_path) == [dead]
    finally:
        os.close(fd)
    assert set(tmp_path.iterdir()) == kept | {held}
    assert sweep_stale(tmp_path) == [held]  # once nobody holds it


def test_a_work_folder_is_locked_while_in_use_and_removed_after(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the stdlib's: the default folder
    with work_folder() as folder:
        assert folder.parent == tmp_path and folder.name.startswith(PREFIX)
        assert sorted(p.name for p in folder.iterdir()) == [LOCK]
        assert sweep_stale(tmp_path) == [] and folder.is_dir()
        (folder / "diagnosis-north.csv").write_text("t\n")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def diagnosable_store(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """42 h of a kit's minutes (``shifted_kit``), a diagnosis due; each test copies it."""
    db = tmp_path_factory.mktemp("kit") / "gw.db"
    end = shifted_kit(db)
    store = Store(db)
    store.set_meta("diagnosis_last", repr(end - 25 * 3600))  # the last run a day ago: one is due
    store.close()
    return db, end


def children_running(pid: int, word: str) -> list[int]:
    """Processes whose parent is ``pid`` and whose command line holds ``word`` (zombies not)."""
    out = []
    for p in filter(str.isdigit, os.listdir("/proc")):
        try:
            state, ppid = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[:2]
            cmd = Path(f"/proc/{p}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
        if int(ppid) == pid and state != "Z" and word in cmd:
            out.append(int(p))
    return out


def gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state == "Z"  # ended, not yet reaped by whoever adopted it


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_stop_mid_diagnosis_removes_the_work_folder_and_ends_the_subprocess(
        tmp_path: Path, diagnosable_store: tuple[Path, float], signum: signal.Signals) -> None:
    """systemd's stop (SIGTERM) or a Ctrl-C (SIGINT) while the diagnosis subprocess reads the
    exported minutes from the work folder: the gateway kills it, removes the folder, exits 0."""
    src, end = diagnosable_store
    copy_store(src, tmp_path / "gw.db")
    cfg = write_config(tmp_path, anchor=time.time() - (end - EPOCH), scale=1.0,
                       diagnosis="every_hours = 24\ndays = 2.0\nmin_days = 1.5\ntimeout_s = 600")
    gw = GatewayProcess(cfg)  # its $TMPDIR: tmp_path
    try:
        gw.start()
        assert gw.proc is not None
        pid = gw.proc.pid
        (child,) = wait_for(lambda: children_running(pid, "gateway diagnose"), 120,
                            "the diagnosis subprocess")
        (folder,) = work_folders(tmp_path)
        assert (folder / "diagnosis-north.csv").is_file()  # what the subprocess reads
        gw.proc.send_signal(signum)
        assert gw.proc.wait(timeout=60) == 0
        wait_for(lambda: gone(child), 60, "the diagnosis subprocess to end")
    finally:
        gw.kill()
    assert list(tmp_path.glob("serra-*")) == []

"""``make run`` (``python -m training run``): the whole kit on loopback, the real firmware under
MicroPython at 300× (600× for the bounded run: its 75 minutes in 7.5 s). Without a terminal it
runs a bounded time and prints a summary whose numbers hold together; on a terminal (tmux,
80×24) it shows the status screen and Ctrl-C stops everything. Either way no process of the run
survives it."""

from __future__ import annotations

import contextlib
import ipaddress
import json
import os
import re
import shlex
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gateway.service.workdir import PREFIX
from tests.gateway_harness import wait_for
from training.kitsim import micropython

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(micropython() is None, reason="micropython not installed")


def count_rows(db: Path, table: str) -> int:
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return conn.execute(f"SELECT count(*) FROM {table}").fetchone()[0]
    finally:
        conn.close()


def group_gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


def listening_tcp(pgid: int) -> list[ipaddress.IPv4Address | ipaddress.IPv6Address]:
    """The addresses the processes of group ``pgid`` listen on over TCP (Linux /proc)."""
    inodes = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[2]) != pgid:
                continue
            for fd in os.listdir(f"/proc/{pid}/fd"):
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
                if link.startswith("socket:["):
                    inodes.add(link[8:-1])
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue  # a process that ended meanwhile
    addrs: list[ipaddress.IPv4Address | ipaddress.IPv6Address] = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # 0A: LISTEN; the address in host-order words
                h = f[1].rsplit(":", 1)[0]
                raw = b"".join(bytes.fromhex(h[i:i + 8])[::-1] for i in range(0, len(h), 8))
                addrs.append(ipaddress.ip_address(raw))
    return addrs


def on_loopback(a: ipaddress.IPv4Address | ipaddress.IPv6Address) -> bool:
    mapped = a.ipv4_mapped if isinstance(a, ipaddress.IPv6Address) else None
    return a.is_loopback or bool(mapped and mapped.is_loopback)


def run_env(tmp_path: Path, **extra: str) -> dict[str, str]:
    """The run's environment: $TMPDIR the test's ``tmp`` folder (made here), so that the
    gateway's work folder (gateway/service/workdir.py) lands there, not in /tmp: a run whose
    gateway is killed (a second Ctrl-C, a failed test's clean-up) leaves it behind."""
    (tmp_path / "tmp").mkdir(exist_ok=True)
    return {**os.environ, "TMPDIR": str(tmp_path / "tmp"), **extra}


def in_tmp(tmp_path: Path) -> list[str]:
    """What the run has in its $TMPDIR (``run_env``): the running gateway's work folder."""
    return [PREFIX if p.name.startswith(PREFIX) else p.name for p in (tmp_path / "tmp").iterdir()]


def test_bounded_run_without_a_terminal_prints_a_consistent_summary(tmp_path: Path) -> None:
    out, log = tmp_path / "run", tmp_path / "stdout.txt"
    # a user's shell, where `python` is not the venv's (make run calls .venv/bin/python)
    venv_bin = os.path.dirname(sys.executable)
    env = run_env(tmp_path, PATH=os.pathsep.join(d for d in os.environ.get("PATH", "").split(os.pathsep)
                                                 if os.path.abspath(d) != venv_bin))
    # 300×: the run lives ~15 s after its "process group" line, the window the checks made while
    # it runs need on a loaded machine (600× left 7.5 s: little margin for a stalled test process)
    with log.open("w") as stdout:
        proc = subprocess.Popen([sys.executable, "-m", "training", "run", "--minutes", "75", "--scale",
                                 "300", "--no-calibrate", "--out", str(out)], cwd=tmp_path,
                                stdout=stdout, stderr=subprocess.STDOUT, text=True,
                                stdin=subprocess.DEVNULL, env=env)
    try:
        # while it runs: everything listens on loopback only, as the README says
        started = wait_for(lambda: re.search(r"process group (\d+)", log.read_text())
                           or proc.poll() is not None, 300, "the kit to start")
        assert started is not True, log.read_text()
        listening = listening_tcp(int(started[1]))
        assert listening and all(map(on_loopback, listening)), listening
        assert in_tmp(tmp_path) == [PREFIX]  # in the test's folder, not in /tmp
        assert proc.wait(600) == 0, log.read_text()
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(60)
    text = log.read_text()
    assert "\x1b" not in text
    pgid = int(re.search(r"process group (\d+)", text)[1])
    assert group_gone(pgid), "a process of the run survived it"
    assert list((tmp_path / "tmp").iterdir()) == []  # the gateway stopped: its folder gone
    s = json.loads((out / "summary.json").read_text())
    # every record the gateway stored was made by the kit; each became an inside and an outside
    # measurement (kit 7 is both sides); everything made was published, and received once
    assert s["kit_records"] >= s["stored"] >= 50
    assert s["measurements"] == 2 * s["stored"]
    assert s["made"] == s["published"] == s["received"] > s["measurements"]
    assert s["pending"] == 0
    # the estimator steps once per stored minute; records drifting 57-63 s apart (a loaded
    # machine at 300×) put two in some minutes: 74 records, 69 minutes in one busy run
    minutes = count_rows(out / "serra.db", "minute")
    assert 50 <= minutes <= s["stored"]  # every stored minute holds a record or more
    assert minutes - 3 <= s["estimated"] <= minutes
    assert 70 <= s["minutes"] <= 76
    skill = {k["horizon_min"]: k for k in s["skill"]}
    assert sorted(skill) == [15, 30, 60] and skill[15]["n"] > 0
    assert s["findings"] == []
    for want in (f"records   made by the kit {s['kit_records']} · stored by the gateway {s['stored']}",
                 f"published on Zenoh {s['published']}", f"received by the subscriber {s['received']}",
                 "forecast  MAE 15 min", "(persistence ", "findings  none"):
        assert " ".join(want.split()) in " ".join(text.split()), want
    assert "Traceback" not in (out / "gateway.log").read_text()
    # the command it prints to look again works as printed, in the same shell and folder
    again = shlex.split(re.search(r"look again: (.+)", text)[1])
    assert again[1:4] == ["-m", "gateway", "status"], again
    r = subprocess.run([*again, "--once"], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=120)
    assert "farm demo-farm · greenhouse north" in r.stdout, r.stdout + r.stderr
    # the gateway stopped cleanly: said at once, not "running" until its heartbeat goes stale
    assert r.returncode == 1 and "ATTENTION: the gateway is not running" in r.stdout, r.stdout
    assert "Service    NOT RUNNING" in r.stdout, r.stdout
    # no virtual ventilation sensor in make run's house, and the screen says why (README, "make
    # run": both shipped sensors learnt the vented 877 m2 house, this one is the 0.68 m2 prototype)
    assert "Ventilation no virtual sensor: shipped ones fit almeria-palmerillas only" in r.stdout
    assert count_rows(out / "serra.db", "estimates WHERE source='vsensor'") == 0


def process_group_of(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[2])


@pytest.mark.parametrize(("signum", "said"), [(signal.SIGINT, "interrupted"),
                                             (signal.SIGTERM, "SIGTERM")])
def test_a_signal_during_the_set_up_stops_it_exits_128_plus_its_number_and_leaves_no_process(
        tmp_path: Path, signum: signal.Signals, said: str) -> None:
    """SIGINT (a Ctrl-C) or SIGTERM once the gateway is up and the subscriber starting (before
    the kit and the screen, or just after on a loaded machine): the run did not do what was
    asked, so the exit status says so (128 + the signal's number, as a shell reports it: 130,
    143), and every child is gone. Both exited 0; SIGTERM even went on to start the kit and
    wrote a summary. A day of minutes (288 s at 300x): the run cannot end by itself first."""
    proc, out, log, gateway = start_a_day_run(tmp_path)
    groups: set[int] = set()
    try:
        up = wait_for(lambda: "gateway ready" in log.read_text() or proc.poll() is not None, 300,
                      "the gateway to be ready")
        assert up is True and proc.poll() is None, log.read_text()
        groups = {process_group_of(pid) for pid in pids_of(gateway)}
        assert groups, "the gateway is not running"
        assert in_tmp(tmp_path) == [PREFIX]  # in the test's folder, not in /tmp
        proc.send_signal(signum)
        assert proc.wait(180) == 128 + signum, log.read_text()
        left = [g for g in groups if not group_gone(g)], pids_mentioning(out)  # before our kill
    finally:
        kill_what_is_left(proc, groups, out)
    text = log.read_text()
    assert f"stopped: {said}" in text and "Traceback" not in text, text
    if "kit 7 started" not in text:  # stopped in the set-up: nothing ran, nothing to sum up
        assert "summary:" not in text and not (out / "summary.json").exists()
    assert left == ([], []), f"a process of the run survived the Ctrl-C: {left}"
    assert list((tmp_path / "tmp").iterdir()) == []  # the gateway stopped: its folder gone


def test_ctrl_c_again_while_stopping_kills_the_children_and_exits_130(tmp_path: Path) -> None:
    """A second Ctrl-C while the run stops its children: Python's default handler raised in the
    middle of the wait for one of them, so the run died of SIGINT with a traceback and left the
    subscriber (or the gateway) running in its process group. Now it kills the group at once.
    A day of minutes (288 s at 300x): the run cannot end by itself before the first Ctrl-C."""
    proc, out, log, gateway = start_a_day_run(tmp_path)
    groups: set[int] = set()
    try:
        up = wait_for(lambda: "subscriber ready" in log.read_text() or proc.poll() is not None,
                      300, "the subscriber to be ready")
        assert up is True and proc.poll() is None, log.read_text()
        groups = {process_group_of(pid) for pid in pids_of(gateway)}
        assert groups, "the gateway is not running"
        proc.send_signal(signal.SIGINT)
        stopping = wait_for(lambda: "stopping the kit" in log.read_text() or proc.poll() is not None,
                            180, "the run to start stopping")
        assert stopping is True, log.read_text()
        proc.send_signal(signal.SIGINT)  # during the stop, or just after: the same either way
        assert proc.wait(180) == 130, log.read_text()
        left = [g for g in groups if not group_gone(g)], pids_mentioning(out)  # before our kill
    finally:
        kill_what_is_left(proc, groups, out)
    text = log.read_text()
    assert "Traceback" not in text, text
    assert left == ([], []), f"a process of the run survived the second Ctrl-C: {left}"


def test_ctrl_c_mid_run_sums_up_the_span_the_kit_ran_not_the_stopping(tmp_path: Path) -> None:
    """A Ctrl-C mid-run (headless; the screen's quit ends the same way): exit 130 and a summary
    whose span ends where the stop began. It ended when the summary was written, after the
    gateway and the subscriber had stopped: seconds the kit no longer ran, two simulated minutes
    each at 120× (148 minutes against 137 records). The gateway, stopped after the kit, writes
    its clock as it stops (gateway_status): the span must end before it."""
    proc, out, log, gateway = start_a_day_run(tmp_path)
    groups: set[int] = set()
    try:
        going = wait_for(lambda: " stored " in log.read_text() or proc.poll() is not None, 300,
                         "the run's first progress line")
        assert going is True and proc.poll() is None, log.read_text()
        groups = {process_group_of(pid) for pid in pids_of(gateway)}
        proc.send_signal(signal.SIGINT)
        assert proc.wait(180) == 130, log.read_text()
    finally:
        kill_what_is_left(proc, groups, out)
    text = log.read_text()
    assert "stopped: interrupted" in text and "summary:" in text, text
    s = json.loads((out / "summary.json").read_text())
    conn = sqlite3.connect(f"file:{out / 'serra.db'}?mode=ro", uri=True)
    try:
        (row,) = conn.execute("SELECT value FROM gateway_status WHERE name='gateway'").fetchone()
    finally:
        conn.close()
    gw = json.loads(row)
    assert gw["stopped"] is not None and s["kit_records"] > 0, (gw, s)
    assert s["start"] < s["end"] <= gw["clock_now"], (s, gw)


def sigint_as_at_a_terminal() -> None:
    """In the child before exec: SIGINT back to its default. A suite started in the background
    by a shell without job control (``make test &`` in a script, a CI runner) inherits SIGINT
    ignored, and a Python started so never raises KeyboardInterrupt: the Ctrl-C these tests
    send would do nothing (measured: the run ended by itself, exit 0, or ran on past 180 s)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_a_day_run(tmp_path: Path) -> tuple[subprocess.Popen, Path, Path, str]:
    """``training run`` headless for a day of minutes (288 s at 300x: it cannot end by itself
    before a test's signal), SIGINT as at a terminal; (the process, its --out, its log, the
    gateway's command line)."""
    out, log = tmp_path / "run", tmp_path / "stdout.txt"
    with log.open("w") as stdout:
        proc = subprocess.Popen([sys.executable, "-m", "training", "run", "--minutes", "1440",
                                 "--scale", "300", "--no-calibrate", "--out", str(out)], cwd=tmp_path,
                                stdout=stdout, stderr=subprocess.STDOUT, text=True,
                                stdin=subprocess.DEVNULL, preexec_fn=sigint_as_at_a_terminal,
                                env=run_env(tmp_path))
    return proc, out, log, f"{sys.executable} -m gateway run --config {out / 'gateway.toml'}"


def kill_what_is_left(proc: subprocess.Popen, groups: set[int], out: Path) -> None:
    """A failed test leaves nothing behind either: the run, its groups, anything naming ``out``."""
    if proc.poll() is None:
        proc.kill()
        proc.wait(60)
    for pgid in groups:
        if not group_gone(pgid):
            os.killpg(pgid, signal.SIGKILL)
    for pid in pids_mentioning(out):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def pids_mentioning(folder: Path) -> list[int]:
    """Processes whose command line names ``folder`` (the run's children name its --out)."""
    return [pid for pid in pids_of("") if str(folder) in cmdline(pid)]


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return ""


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux not installed")
def test_on_a_terminal_the_status_screen_shows_and_ctrl_c_stops_everything(tmp_path: Path) -> None:
    out, name = tmp_path / "run", f"serra-run-{os.getpid()}"
    tmux = private_tmux(tmp_path)
    cmd = (f"{sys.executable} -m training run --scale 300 --no-calibrate --out {out}; "
           f"echo EXIT=$?; sleep 600")
    subprocess.run([*tmux, "new-session", "-d", "-s", name, "-x", "80", "-y", "24", "-c",
                    str(tmp_path), cmd], check=True, timeout=60, env=run_env(tmp_path))

    def screen() -> str:
        return subprocess.run([*tmux, "capture-pane", "-p", "-t", name], capture_output=True,
                              text=True, timeout=60).stdout

    try:
        shot = wait_for(lambda: s if "ours|persistence" in (s := screen()) else "", 180,
                        "the status screen with a scored forecast")
        lines = shot.splitlines()
        assert "farm demo-farm · greenhouse north (1/1)" in lines[0] and "×300" in lines[0]
        assert in_tmp(tmp_path) == [PREFIX]  # in the test's folder, not in /tmp
        assert "q quit" in lines[-1] and len(lines) <= 24
        print("\n--- make run, 80x24 ---\n" + shot)
        subprocess.run([*tmux, "send-keys", "-t", name, "C-c"], check=True, timeout=60)
        after = wait_for(lambda: s if "EXIT=" in (s := screen()) else "", 180, "the run to stop")
    finally:
        log = subprocess.run([*tmux, "capture-pane", "-p", "-J", "-S", "-200", "-t", name],
                             capture_output=True, text=True, timeout=60).stdout
        subprocess.run([*tmux, "kill-session", "-t", name], timeout=60)
    assert "EXIT=0" in after, log
    assert "summary:" in log and "received by the subscriber" in " ".join(log.split())
    pgid = int(re.search(r"process group (\d+)", log)[1])
    deadline = time.monotonic() + 60  # a generous bound: the sweep is quick, the machine may not be
    while not group_gone(pgid):
        assert time.monotonic() < deadline, "a process of the run survived Ctrl-C"
        time.sleep(0.1)
    s = json.loads((out / "summary.json").read_text())
    assert s["published"] == s["received"] and s["stored"] > 0
    assert list((tmp_path / "tmp").iterdir()) == []  # the gateway stopped: its folder gone


def private_tmux(folder: Path) -> list[str]:
    """tmux on a server of the test's own (its socket in ``folder``): not the user's default
    server, and no /tmp/tmux-UID left behind."""
    return ["tmux", "-S", str(folder / "tmux.sock")]


def pids_of(command: str) -> list[int]:
    """Processes whose command line starts with ``command`` (not a shell that runs it)."""
    out = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().startswith(command):
                out.append(int(pid))
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
    return out


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux not installed")
def test_a_terminal_that_hangs_up_under_a_session_leader_that_waits_stops_the_run(
        tmp_path: Path) -> None:
    """A dropped SSH session or a killed tmux pane with make as the session leader: the kernel
    sends SIGHUP to the leader only, and make catches it and waits for its child. The shell here
    plays make (it ignores SIGHUP and waits); the run must notice the terminal is gone, stop
    everything and write its summary."""
    out, name = tmp_path / "run", f"serra-hup-{os.getpid()}"
    tmux = private_tmux(tmp_path)
    argv = f"{sys.executable} -m training run --scale 300 --no-calibrate --out {out}"
    cmd = f"trap '' HUP; {argv}; true"  # `; true`: the shell waits, it does not exec the run
    subprocess.run([*tmux, "new-session", "-d", "-s", name, "-x", "80", "-y", "24", "-c",
                    str(tmp_path), cmd], check=True, timeout=60, env=run_env(tmp_path))
    run = gw = []
    try:
        wait_for(lambda: "farm demo-farm" in subprocess.run(
            [*tmux, "capture-pane", "-p", "-t", name], capture_output=True, text=True,
            timeout=60).stdout, 180, "the status screen")
        run = pids_of(argv)
        gw = pids_of(f"{sys.executable} -m gateway run --config {out / 'gateway.toml'}")
        assert len(run) == 1 and len(gw) == 1, (run, gw)
        assert in_tmp(tmp_path) == [PREFIX]  # in the test's folder, not in /tmp
        subprocess.run([*tmux, "kill-session", "-t", name], timeout=60)  # the terminal hangs up
        wait_for(lambda: not pids_of(argv) and group_gone(gw[0]), 180,
                 "the run and every process of its group to stop")
    finally:
        subprocess.run([*tmux, "kill-session", "-t", name], capture_output=True, timeout=60)
        for pid in run:  # a failed test leaves nothing behind either
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        for pgid in gw:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pgid, signal.SIGKILL)
    s = json.loads((out / "summary.json").read_text())
    assert s["published"] == s["received"] and s["stored"] > 0
    assert list((tmp_path / "tmp").iterdir()) == []  # the gateway stopped: its folder gone

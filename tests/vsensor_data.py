"""Small data and a tiny trained sensor shared by the virtual-sensor tests (built once per run).

The online estimator runs with a small budget (TINY) so that both replays of 1.5 simulated days
take seconds; the network is small (8-8) and trained for a few epochs. Real training runs from
``python -m training.vsensor train`` (docs/vsensor.md), never in CI.

Under xdist (``make test``: two workers, one test file each) the vsensor files land on both
workers, and each used to simulate, replay and train the same things again (~25 s). The workers
of one run share a folder (``PYTEST_XDIST_TESTRUNUID``), build each file and model once under a
lock, and reuse what another worker has finished (a marker written after it, with its settings).
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import functools
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from training.simulate import PRESETS, simulate
from training.simulate.control import GrowerVents

TINY = {"t_in": {"iterations": 2, "bats": 4, "every": 15}, "i_in": {"iterations": 2, "bats": 4}}
"""The estimator budget of every replay the tiny sensors are trained on and fed with: the air's
search every 15th sample (as the demo test's replay, tests/test_demo.py QUICK) cuts a replay's
time by ~3 (1.80 -> 0.58 s CPU for a simulated day); what the tests check (live equals batch,
CLI equals training, reproducible, refusals) holds at any budget."""
GREENHOUSE = "almeria-palmerillas"


def run_folder(run: str) -> Path:
    """The folder the xdist workers of run ``run`` share (tests/conftest.py removes it when the
    run ends)."""
    return Path(tempfile.gettempdir()) / f"serra-vsensor-{run}"


def workdir() -> Path:
    """One folder for every xdist worker of this run, else one for this process, removed when
    it exits."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if run:
        path = run_folder(run)
        path.mkdir(exist_ok=True)
        return path
    return _own_folder()


@functools.cache
def _own_folder() -> Path:
    path = Path(tempfile.mkdtemp(prefix="serra-vsensor-"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


@contextlib.contextmanager
def _build_once(name: str, settings: str) -> Iterator[bool]:
    """True when the caller must build ``name`` (no worker of this run has finished it with these
    ``settings``); one builder at a time, the others wait and then reuse it."""
    folder = workdir()
    done = folder / f"{name}.done"
    with open(folder / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        build = not (done.exists() and done.read_text() == settings)
        yield build
        if build:  # not reached when the build raised: the next caller builds again
            done.write_text(settings)


@functools.cache
def kit_csv(name: str, start: str, days: float, grower: bool, seed: int) -> Path:
    """A simulated Almería-type house with vent openings, as a kit CSV."""
    path = workdir() / f"{name}.csv"
    with _build_once(f"csv-{name}", repr((start, days, grower, seed))) as build:
        if build:
            plant = PRESETS["almeria"]
            if grower:
                plant = plant.with_(controller=GrowerVents(seed=seed))
            simulate(plant, "almeria", start, days, seed=seed).write(path)
    return path


def train_files() -> list[Path]:
    return [kit_csv("train-grower", "2020-05-02", 1.5, True, 3),
            kit_csv("train-controller", "2020-07-20", 1.5, False, 4)]


def test_file() -> Path:
    return kit_csv("test-grower", "2020-06-01", 1.0, True, 5)


@functools.cache
def tiny_model(tag: str = "a", ensemble: int = 1, kind: str = "almeria", **options) -> Path:
    """Train the tiny sensor on the fluxes of the ``kind`` model (cache shared between tags, so
    a second tag only re-fits); ``options``: more keyword arguments of ``train`` (e.g. ``target``)."""
    from threadpoolctl import threadpool_limits

    from gateway.greenhouse import load_greenhouse
    from training.vsensor.train import train

    out = workdir() / tag / "tiny.onnx"
    settings = repr((ensemble, kind, sorted(options.items())))
    with _build_once(f"model-{tag}", settings) as build, threadpool_limits(1):
        if build:
            train([str(p) for p in train_files()], load_greenhouse(GREENHOUSE), kind, out,
                  workdir() / "cache", TINY, seed=0, hidden=(8, 8), epochs=8, rounds=1,
                  ensemble=ensemble, **options)
    return out


@functools.cache
def cli_run(model: Path) -> tuple[int, dict, Path]:
    """``python -m gateway vsensor --json --out`` of ``model`` on the test file (the default
    almeria kind): (its exit code, its JSON report, its CSV). Run once for every file and worker
    of a run: test_vsensor_runtime checks the CLI's output on it and test_vsensor_train holds
    training's held-out scores equal to its figures (each ran the same two replays again)."""
    import io

    from gateway.cli import main

    folder = workdir() / f"cli-{model.parent.name}"
    code_file, report, out = folder / "code", folder / "report.json", folder / "flows.csv"
    with _build_once(f"cli-{model.parent.name}", repr(str(model))) as build:
        if build:
            folder.mkdir(exist_ok=True)
            with contextlib.redirect_stdout(io.StringIO()) as stdout:
                code = main(["vsensor", "--model", str(model), "--data", str(test_file()),
                             "--greenhouse", GREENHOUSE, "--model-kind", "almeria", "--json",
                             "--out", str(out)])
            report.write_text(stdout.getvalue())
            code_file.write_text(str(code))
    return int(code_file.read_text()), json.loads(report.read_text()), out


def rewrite_metadata(src: Path, dst: Path, **changes) -> Path:
    """A copy of the ONNX model ``src`` at ``dst`` with metadata entries changed (None: removed;
    non-strings JSON-encoded): what the runtime's refusals are tested on."""
    import onnx  # the training extra

    model = onnx.load(str(src))
    props = {p.key: p.value for p in model.metadata_props}
    for k, v in changes.items():
        if v is None:
            props.pop(k, None)
        else:
            props[k] = v if isinstance(v, str) else json.dumps(v)
    del model.metadata_props[:]
    onnx.helper.set_model_props(model, props)
    onnx.save(model, str(dst))
    return dst


def novent_run(gh):
    """The test file's no-vent replay (what the sensor is fed), from its cached segment: the
    replay training's tests make of it anyway (seed 0, TINY), made once per run for every file
    and worker instead of once more per file. A fresh object on each call."""
    from training.vsensor.dataset import build_segment

    return _as_run(build_segment(test_file(), gh, "almeria", workdir() / "cache", TINY))


def _as_run(seg):
    """A training segment as the ``AdaptiveRun`` the gateway's sensor is fed (no parameters)."""
    import numpy as np

    from gateway.vsensor.adaptive import AdaptiveRun

    return AdaptiveRun(seg.time, seg.x, seg.fluxes, np.empty((len(seg.time), 0)), [])


def live_and_batch(model: Path, gh, extra: tuple[str, ...] = (), clamp_inputs: bool = False):
    """(sensor, live flows, batch flows) of ``model`` on the test file: the gateway's sensor
    run step by step (``run_sensor``) beside training's batch closed loop (``simulate_model``)
    on the same replayed segment, which the tests hold equal (``clamp_inputs``: both clamp)."""
    from gateway.vsensor import VentSensor
    from gateway.vsensor.batch import run_sensor
    from training.vsensor.dataset import build_segment
    from training.vsensor.errors import simulate_model

    seg = build_segment(test_file(), gh, "almeria", workdir() / "cache", TINY, extra=extra)
    batch = simulate_model(model, [seg], gh, "almeria", clamp_inputs)[0]
    nov = _as_run(seg)
    sensor = VentSensor(model, gh, "almeria", clamp_inputs=clamp_inputs)
    return sensor, run_sensor(sensor, nov).flow, batch

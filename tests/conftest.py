"""Shared fixtures: real shipped weather, resampled, driving synthetic inside conditions."""

from __future__ import annotations

import logging
import shutil
import signal
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from gateway.greenhouse import load_greenhouse
from gateway.series import Series
from gateway.vsensor.ort import telemetry_off
from training.weather import load_bleiswijk, to_minutes

telemetry_off()  # before any test imports onnxruntime (gateway/vsensor/ort.py)


def _terminate_as_interrupt(signum: int, frame: object) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends pytest at once
    raise KeyboardInterrupt(f"signal {signum}")


def pytest_configure(config: pytest.Config) -> None:
    # By default a SIGTERM (a CI timeout, a killed job) ends pytest on the spot, and the routers,
    # gateways and kits that tests start in sessions of their own outlive it. As an interrupt it
    # unwinds the tests' with-blocks and fixture teardowns, which stop them.
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _terminate_as_interrupt)
    # The controller of an xdist run names the run itself (xdist would draw the same kind of
    # id), so that it can remove the folder its workers share (tests/vsensor_data.py) at the end.
    if (not hasattr(config, "workerinput") and config.pluginmanager.hasplugin("xdist")
            and config.getoption("testrunuid", None) is None):
        config.option.testrunuid = uuid.uuid4().hex


def pytest_unconfigure(config: pytest.Config) -> None:
    run = getattr(config.option, "testrunuid", None)
    if run and not hasattr(config, "workerinput"):
        from tests.vsensor_data import run_folder

        shutil.rmtree(run_folder(run), ignore_errors=True)


@pytest.fixture(autouse=True)
def _root_logging_restored() -> Iterator[None]:
    """A CLI main run in-process (``--log-level``) sets root handlers on the test's captured
    stderr; left in place they write to a closed file from later tests' threads."""
    handlers, level = logging.root.handlers[:], logging.root.level
    yield
    logging.root.handlers[:] = handlers
    logging.root.setLevel(level)


@pytest.fixture(scope="session")
def weather_minutes() -> dict[str, np.ndarray]:
    return to_minutes(load_bleiswijk())


def almeria_like_series(weather: dict[str, np.ndarray], days: int, first_day: int = 0) -> Series:
    """Bleiswijk weather with plausible inside inputs for the almeria model: soil following
    the daily mean, vents opening with radiation, constant humidity and LAI."""
    a = 60 + first_day * 1440
    n = days * 1440
    cols = {k: weather[k][a : a + n].copy() for k in ("t_out", "rh_out", "i_glob", "wind")}
    kernel = np.ones(720) / 720
    cols["t_soil"] = np.convolve(np.pad(cols["t_out"], (360, 359), mode="edge"), kernel, "valid") + 4
    cols["vent_roof"] = np.clip((cols["i_glob"] - 100) / 3, 0, 100)
    cols["vent_side"] = np.clip((cols["i_glob"] - 300) / 3, 0, 100)
    cols["rh_in"] = np.full(n, 75.0)
    cols["t_in"] = cols["t_out"] + 3.0
    cols["lai"] = np.full(n, 2.5)
    return Series(weather["time"][a : a + n], 60.0, cols, source="almeria-like")


@pytest.fixture(scope="session")
def almeria_gh():
    return load_greenhouse("almeria-palmerillas")


@pytest.fixture(scope="session")
def prototype_gh():
    return load_greenhouse("biskra-prototype")


@pytest.fixture(scope="session")
def filled(tmp_path_factory: pytest.TempPathFactory):
    """A store filled the way the service fills it (tests/status_store.py; its clock is the
    trace's, not the wall's), once per worker for the status screen's files (test_status.py,
    test_status_app.py). Read only: a test changes its own copy (``store``)."""
    from tests.status_store import fill_store

    return fill_store(tmp_path_factory.mktemp("status") / "serra.db", minutes=130)


@pytest.fixture
def store(filled, tmp_path: Path):
    """A copy of the ``filled`` store this test may change."""
    from tests.status_store import Filled

    path = tmp_path / "serra.db"
    shutil.copy(filled.path, path)
    return Filled(path, filled.now, filled.minutes)


@pytest.fixture(scope="session")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The firmware and gateway bundles built by images/build.py (``make images``) into a
    temporary folder, once per worker for test_images.py and test_images_units.py (read only)."""
    from tests.images_common import build

    out = tmp_path_factory.mktemp("images")
    assert build.main(["--out", str(out)]) == 0
    return out

"""``make run``'s gateway and calibration see the sun of the weather the kit is fed (Bleiswijk),
not the Biskra preset's: the model's cloudiness (so its sky temperature) and the clear-sky
outlook are computed from the sun's position at the greenhouse's ``[site]``."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from gateway.greenhouse import PRESET_DIR
from gateway.service.config import load_config
from gateway.service.resources import prepare
from gateway.store.keys import write_keys
from training.appliance import files
from training.kitsim import KitClock
from training.simulate.weather import load_weather

ROOT = Path(__file__).resolve().parents[1]


def kit_weather_latitude() -> float:
    """The latitude of the weather the run's kit trace is simulated on (kitsim's default)."""
    import inspect

    from training.kitsim.kit import simulated_trace

    source = inspect.signature(simulated_trace).parameters["weather"].default
    wx = load_weather(source, np.datetime64("2009-11-01T00:00"), 0.1)
    return wx.latitude


def test_the_run_gateway_greenhouse_sits_where_its_weather_was_measured(tmp_path: Path) -> None:
    write_keys(tmp_path / "keys.txt", {files.DEVICE: bytes(range(100, 116))})
    clock = KitClock(120.0, float(np.datetime64("2009-11-01T08:00", "s").astype("int64")))
    files.write_config(tmp_path, clock, None)
    cfg = load_config(tmp_path / "gateway.toml")
    (res,) = prepare(cfg)
    lat, lon = files.weather_site()
    assert lat == pytest.approx(kit_weather_latitude())
    assert (res.gh.site.latitude, res.gh.site.longitude) == (lat, lon)
    assert (cfg.greenhouses[0].latitude, cfg.greenhouses[0].longitude) == (lat, lon)
    # everything else is the preset's, unchanged
    ours = tomllib.loads((tmp_path / "greenhouse.toml").read_text())
    preset = tomllib.loads((PRESET_DIR / f"{files.PRESET}.toml").read_text())
    assert ours.pop("site") == {"latitude": lat, "longitude": lon} != preset.pop("site")
    assert ours == preset


def test_the_run_calibrates_at_the_weather_site(tmp_path: Path) -> None:
    cmd = files.calibrate_command(tmp_path / "d.csv", tmp_path / "p.toml")
    lat, lon = files.weather_site()
    assert cmd[cmd.index("--site") + 1] == f"{lat},{lon}"
    assert cmd[cmd.index("--greenhouse") + 1] == files.PRESET


def test_the_run_uses_the_shipped_model_for_its_calibration_and_its_gateway(tmp_path: Path) -> None:
    """make run runs the shipped example's model (images/gateway/gateway.toml), calibrated as such."""
    shipped = tomllib.loads((ROOT / "images" / "gateway" / "gateway.toml").read_text("utf-8"))
    model = shipped["greenhouse"][0]["model"]
    cmd = files.calibrate_command(tmp_path / "d.csv", tmp_path / "p.toml")
    assert cmd[cmd.index("--model") + 1] == model
    write_keys(tmp_path / "keys.txt", {files.DEVICE: bytes(range(100, 116))})
    files.write_config(tmp_path, KitClock(120.0, 0.0), None)
    assert load_config(tmp_path / "gateway.toml").greenhouses[0].model == model
    # --model prototype: the four-parameter model, calibrated and run as such
    cmd = files.calibrate_command(tmp_path / "d.csv", tmp_path / "p.toml", "prototype")
    assert cmd[cmd.index("--model") + 1] == "prototype"
    files.write_config(tmp_path, KitClock(120.0, 0.0), None, "prototype")
    assert load_config(tmp_path / "gateway.toml").greenhouses[0].model == "prototype"

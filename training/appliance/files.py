"""The files and commands ``make run`` (training/appliance/cli.py) sets the kit up with: the
greenhouse placed where its weather was measured, the gateway's config on loopback with the
TEST/DEMO clock, and the calibration command on two earlier days."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from training.appliance.procs import ChildError

if TYPE_CHECKING:
    from training.kitsim import KitClock

DEVICE = 7
GREENHOUSE = "north"
PRESET = "biskra-prototype"  # the kit's greenhouse: the thesis's prototype (table 2)
MODEL = "prototype+vent_control"  # the shipped example's (images/gateway/gateway.toml); on this
# house's minutes, each model with its own calibration, its forecasts beat the plain prototype's
# (docs/effects.md, "Forecasts: the vent controller", the demo house)


def weather_site() -> tuple[float, float]:
    """Where the run's weather was measured (Bleiswijk) [deg N, deg E]: the sun the model's
    cloudiness (sky temperature) and the clear-sky outlook are computed for must be the sun of
    that weather, not the preset's Biskra sun (as ``make demo`` passes ``--site``)."""
    from training.simulate.weather import BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE

    return BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE


def calibrate_command(data: Path, params: Path, model: str = MODEL) -> list[str]:
    """``gateway calibrate`` on the two earlier days, at the weather's site."""
    lat, lon = weather_site()
    return [sys.executable, "-m", "gateway", "calibrate", "--data", str(data), "--greenhouse",
            PRESET, "--model", model, "--algorithm", "riwpso", "--seed", "1",
            "--site", f"{lat},{lon}", "--out", str(params)]


def greenhouse_toml() -> str:
    """The preset's description with its ``[site]`` moved to where the weather was measured."""
    from gateway.greenhouse import PRESET_DIR

    lat, lon = weather_site()
    text = (PRESET_DIR / f"{PRESET}.toml").read_text(encoding="utf-8")
    site = (f"[site]              # where the run's weather was measured (Bleiswijk), written by "
            f"python -m training run\nlatitude = {lat}\nlongitude = {lon}\n")
    new, n = re.subn(r"^\[site\][^\n]*\n(?:(?:latitude|longitude)\s*=[^\n]*\n){2}", site, text,
                     flags=re.M)
    if n != 1:
        raise ChildError(f"{PRESET}.toml: no [site] table with latitude and longitude to replace")
    return new


def write_config(out: Path, clock: KitClock, params: Path | None, model: str = MODEL) -> None:
    """``gateway.toml`` and the ``greenhouse.toml`` it names, under ``out``."""
    (out / "greenhouse.toml").write_text(greenhouse_toml(), encoding="utf-8")
    (out / "gateway.toml").write_text(CONFIG.format(
        scale=clock.scale, epoch=clock.epoch, anchor=clock.anchor, device=DEVICE,
        greenhouse=GREENHOUSE, model=model) + (f'params = "{params.name}"\n' if params else ""))


CONFIG = """# Written by python -m training run (make run): the shipped defaults
# (images/gateway/gateway.toml) on loopback, with the TEST/DEMO clock; the greenhouse is the
# biskra-prototype preset at the site of the kit's weather (greenhouse.toml: Bleiswijk).
[gateway]
farm = "demo-farm"
db = "serra.db"
keys = "keys.txt"
status_every_s = 300

[ingest]
listen = "127.0.0.1:0"
maintenance_s = 1

[zenoh]
listen = ["tcp/127.0.0.1:0"]

[diagnosis]
every_hours = 6
days = 1
min_days = 0.5

[clock]
scale = {scale!r}
epoch = {epoch!r}
anchor = {anchor!r}

[[greenhouse]]
name = "{greenhouse}"
greenhouse = "greenhouse.toml"
model = "{model}"
inside = {device}
"""

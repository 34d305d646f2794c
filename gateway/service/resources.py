"""What the config points at, loaded and checked before anything starts: the keys file, each
greenhouse's description, model, calibrated parameters and (optional) virtual ventilation
sensor. Every problem is a :class:`ConfigError` naming the config key."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gateway.greenhouse import Greenhouse, GreenhouseError, load_greenhouse
from gateway.model import build_model, check_parameters
from gateway.model.model import Model
from gateway.model.params_file import ParamsFileError, read_params
from gateway.service.config import ConfigError, GatewayConfig, GreenhouseSettings
from gateway.service.minutes import KIT_COLUMNS
from gateway.service.pipeline import Ventilation
from gateway.store.keys import KeyFileError, load_keys


@dataclass
class GreenhouseResources:
    settings: GreenhouseSettings
    gh: Greenhouse
    model: Model
    theta0: np.ndarray | None
    ventilation: Ventilation | None


def load_ventilation(path: Path, model: Model, gh: Greenhouse) -> Ventilation:
    """The virtual ventilation sensor for ``model`` (gateway/vsensor.py, its own issue).

    The pipeline calls the returned function once per minute with (t, the minute's drivers, the
    model's heat fluxes [W m-2]) and publishes what it returns under ``ventilation``. The sensor
    module provides ``live_sensor(model_path, model, gh)`` returning that function."""
    try:
        from gateway import vsensor  # type: ignore[attr-defined]
    except ImportError:
        raise ValueError("the virtual ventilation sensor (gateway/vsensor.py) is not in this "
                         "build: remove the vsensor key") from None
    factory = getattr(vsensor, "live_sensor", None)
    if factory is None:
        raise ValueError("gateway.vsensor has no live_sensor(model_path, model, gh) to call")
    if not path.exists():
        raise ValueError(f"{path}: no such ONNX model")
    return factory(path, model, gh)


def prepare(cfg: GatewayConfig) -> list[GreenhouseResources]:
    """Load and check everything the config names (raises ConfigError naming the key)."""
    try:
        keys = load_keys(cfg.keys)
    except OSError as e:
        raise ConfigError(f"{cfg.source}: gateway.keys: cannot read {cfg.keys}: "
                          f"{e.strerror or e}") from None
    except (KeyFileError, UnicodeDecodeError) as e:
        raise ConfigError(f"{cfg.source}: gateway.keys: {e}") from None
    out = []
    for i, g in enumerate(cfg.greenhouses, 1):
        where = f"{cfg.source}: greenhouse[{i}]"
        for role in ("inside", "outside"):
            dev = getattr(g, role)
            if dev not in keys:
                raise ConfigError(f"{where}.{role}: device {dev} has no key in {cfg.keys} "
                                  f"(devices there: {', '.join(map(str, sorted(keys))) or 'none'})")
        try:
            gh = load_greenhouse(g.greenhouse)
            model = build_model(g.model, gh)
            check_parameters(model, gh)
        except GreenhouseError as e:
            raise ConfigError(f"{where}.greenhouse: {e}") from None
        missing = [c for c in model.requires if c not in KIT_COLUMNS]
        if missing:
            raise ConfigError(f"{where}.model: the '{g.model}' model needs {', '.join(missing)}, "
                              f"which a Serra kit does not measure (kit: {', '.join(KIT_COLUMNS)})")
        theta0 = None
        if g.params is not None:
            try:
                theta0 = read_params(g.params, model)
            except ParamsFileError as e:
                raise ConfigError(f"{where}.params: {e}") from None
        vent = None
        if g.vsensor is not None:
            try:
                vent = load_ventilation(g.vsensor, model, gh)
            except (ValueError, OSError) as e:
                raise ConfigError(f"{where}.vsensor: {e}") from None
        out.append(GreenhouseResources(g, gh, model, theta0, vent))
    return out

"""What the config points at, loaded and checked before anything starts: the keys file, each
greenhouse's description, model, calibrated parameters and (optional) virtual ventilation
sensor. Every problem is a :class:`ConfigError` naming the config key; what the gateway can
start with but should be told (a starting parameter outside its hard box) is a warning line in
:attr:`GreenhouseResources.warnings`, which ``run --check`` prints and the service logs once."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np

from gateway.greenhouse import Greenhouse, GreenhouseError, Site, load_greenhouse
from gateway.model import build_model, check_parameters
from gateway.model.model import Model
from gateway.model.params_file import ParamsFileError, outside_box, read_params
from gateway.service.config import ConfigError
from gateway.service.minutes import KIT_COLUMNS
from gateway.service.settings import GatewayConfig, GreenhouseSettings
from gateway.service.ventilation import VentilationSensor, load_ventilation
from gateway.store.db import StoreError, open_readonly
from gateway.store.keys import KeyFileError, load_keys


@dataclass
class GreenhouseResources:
    settings: GreenhouseSettings
    gh: Greenhouse
    model: Model
    theta0: np.ndarray | None
    ventilation: VentilationSensor | None
    warnings: tuple[str, ...] = ()  # one line each, naming the config key: not errors


def params_warnings(where: str, g: GreenhouseSettings, theta0: np.ndarray, model: Model,
                    gh: Greenhouse) -> tuple[str, ...]:
    """The starting values of ``g.params`` outside their hard box, one line each naming the
    config key, the greenhouse, the file, the parameter, the box and the value the estimator
    will use (it clips them). A warning, not an error: a file calibrated before the greenhouse's
    bounds were narrowed still starts (the value used is inside the box)."""
    return tuple(f"{where}.params ({g.name}): {o.describe(g.params or '')}"
                 for o in outside_box(theta0, model, gh))


def _check_existing_store(cfg: GatewayConfig) -> None:
    """A gateway.db that exists must be a Serra store (a CSV, the cloud store's file): --check
    says so, not only the start. Read-only, and skipped when this user may not read it (an
    admin checking the service's 0600 store): the service's own start decides then."""
    if not (cfg.db.is_file() and cfg.db.stat().st_size > 0 and os.access(cfg.db, os.R_OK)):
        return
    try:
        open_readonly(cfg.db).close()
    except StoreError as e:
        raise ConfigError(f"{cfg.source}: gateway.db: {e}") from None


def prepare(cfg: GatewayConfig) -> list[GreenhouseResources]:
    """Load and check everything the config names (raises ConfigError naming the key)."""
    folder = cfg.db.parent  # the store is created at start, its folder is not
    if not folder.is_dir():
        raise ConfigError(f"{cfg.source}: gateway.db: folder {folder} "
                          f"{'is not a folder' if folder.exists() else 'does not exist'} "
                          f"(the gateway creates the store {cfg.db.name}, not its folder)")
    if cfg.db.is_dir():
        raise ConfigError(f"{cfg.source}: gateway.db: {cfg.db} is a folder; name the store's file")
    _check_existing_store(cfg)
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
            if gh.site is None and g.latitude is not None and g.longitude is not None:
                gh = replace(gh, site=Site(g.latitude, g.longitude))  # the config's [location]
            model = build_model(g.model, gh)
            check_parameters(model, gh)
        except GreenhouseError as e:
            raise ConfigError(f"{where}.greenhouse: {e}") from None
        missing = [c for c in model.requires if c not in KIT_COLUMNS]
        if missing:
            raise ConfigError(f"{where}.model: the '{g.model}' model needs {', '.join(missing)}, "
                              f"which a Serra kit does not measure (kit: {', '.join(KIT_COLUMNS)})")
        theta0: np.ndarray | None = None
        warnings: tuple[str, ...] = ()
        if g.params is not None:
            try:
                theta0 = read_params(g.params, model, gh)
            except ParamsFileError as e:
                raise ConfigError(f"{where}.params: {e}") from None
            warnings = params_warnings(where, g, theta0, model, gh)
        vent = None
        if g.vsensor is not None:
            try:
                vent = load_ventilation(g.vsensor, gh)  # its own kind (ventilation.py)
            except (ValueError, OSError) as e:
                raise ConfigError(f"{where}.vsensor: {e}") from None
        out.append(GreenhouseResources(g, gh, model, theta0, vent, warnings))
    return out

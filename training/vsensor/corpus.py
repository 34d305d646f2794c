"""The sensor's data: kit CSVs with vent openings, from two generators that share no code.

- The reference simulator (training/simulate) with the Almería-type house, on several sites
  and seasons, the vents moved either by the climate controller (training/simulate/control.py,
  ``VentController``) or by hand (``GrowerVents``: a few visits a day, the evening closing
  sometimes forgotten).
- tests/twonode.py, the independent two-node generator (its own physics and vent controller),
  on the real Bleiswijk weather.

``TRAIN`` and ``TEST`` below are the split the README's figures use: the test site (Biskra)
and season (spring) appear nowhere in training; ``OTHER`` is another house. ``python -m
training.vsensor corpus --out DIR`` writes ``DIR/train``, ``DIR/test``, ``DIR/fresh`` and
``DIR/other`` kit CSVs with the simulator's truth files; ``--hot-dry`` also writes the opt-in
``HOT_DRY`` runs to ``DIR/hot-dry`` (a third climate, not in ``TRAIN``), ``--more-test`` the
``MORE_TEST`` runs to ``DIR/more-test`` (more draws of the test site and season).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from training.simulate import PRESETS, simulate
from training.simulate.control import GrowerVents


@dataclass(frozen=True)
class Run:
    """One generated data set: ``name``, generator (``sim`` or ``twonode``), weather, start
    (UTC), days, vents (``controller`` or ``grower``), seed."""

    name: str
    generator: str
    weather: str
    start: str
    days: float
    vents: str
    seed: int

    def describe(self) -> str:
        what = "two-node generator" if self.generator == "twonode" else "reference simulator"
        return (f"{self.name}: {what}, {self.weather} weather from {self.start}, {self.days:g} d, "
                f"vents by {self.vents}")


TRAIN = (
    Run("almeria-winter-controller", "sim", "almeria", "2020-01-08", 6, "controller", 11),
    Run("almeria-winter-grower", "sim", "almeria", "2020-02-05", 6, "grower", 12),
    Run("almeria-summer-grower", "sim", "almeria", "2020-07-10", 6, "grower", 13),
    Run("almeria-summer-controller", "sim", "almeria", "2020-08-10", 6, "controller", 14),
    Run("almeria-autumn-grower", "sim", "almeria", "2020-10-15", 6, "grower", 15),
    Run("bleiswijk-autumn-controller", "sim", "bleiswijk", "2009-10-21", 6, "controller", 16),
    Run("bleiswijk-autumn-grower", "sim", "bleiswijk", "2009-11-10", 6, "grower", 17),
    Run("twonode-bleiswijk-autumn", "twonode", "bleiswijk", "2009-10-20", 6, "controller", 18),
    Run("almeria-late-summer-grower", "sim", "almeria", "2020-08-25", 6, "grower", 19),
    Run("almeria-early-winter-grower", "sim", "almeria", "2020-12-10", 6, "grower", 20),
    Run("bleiswijk-late-autumn-grower", "sim", "bleiswijk", "2009-11-25", 6, "grower", 23),
)
TEST = (
    Run("biskra-spring-grower", "sim", "biskra", "2019-04-10", 5, "grower", 21),
    Run("biskra-spring-controller", "sim", "biskra", "2019-04-20", 5, "controller", 22),
)
FRESH = (
    Run("almeria-spring-grower", "sim", "almeria", "2020-04-25", 5, "grower", 24),
    Run("biskra-autumn-grower", "sim", "biskra", "2019-10-20", 5, "grower", 25),
)
"""Second held-out set (seventh pass): a season never trained on at a training site, and
another season at the test site; no setting was chosen with them (``out/fresh``)."""
HOT_DRY = (
    Run("seville-summer-grower", "sim", "seville", "2021-07-12", 6, "grower", 26),
    Run("seville-autumn-controller", "sim", "seville", "2021-10-04", 6, "controller", 27),
    Run("seville-winter-controller", "sim", "seville", "2021-01-18", 6, "controller", 28),
)
"""Opt-in training runs at a third climate, inland hot-dry Sevilla (eleventh pass, candidate H;
the winter run added by the twelfth, candidate I, to give the climate its cold season as
Almería has: docs/vsensor.md): never spring (the test season), never Biskra weather; not in
``TRAIN``, so the shipped model and its figures do not depend on them (``corpus --hot-dry``
writes them)."""
MORE_TEST = (
    Run("biskra-spring-grower-2", "sim", "biskra", "2019-03-28", 5, "grower", 41),
    Run("biskra-spring-grower-3", "sim", "biskra", "2019-04-28", 5, "grower", 42),
    Run("biskra-spring-grower-4", "sim", "biskra", "2019-05-10", 5, "grower", 43),
    Run("biskra-spring-controller-2", "sim", "biskra", "2019-04-01", 5, "controller", 44),
    Run("biskra-spring-controller-3", "sim", "biskra", "2019-05-05", 5, "controller", 45),
)
"""More draws of the test site and season (Biskra, spring), fixed before any was scored
(2026-11-28; the rule is stated in docs/vsensor.md "More Biskra spring files"): ``TEST`` is one
5-day file per vent kind, one draw of the weather and of the grower's visits. Opt-in
(``corpus --more-test``); no sensor is trained or chosen on them."""
OTHER = (
    Run("other-house-spring", "sim", "almeria", "2020-04-15", 3, "controller", 31),
)
"""Another house (2 roof flaps instead of 5, one side vent instead of two:
docs/examples/other-house.toml), to show that the sensor flags it rather than trusting itself."""
OTHER_HOUSE = {"roof_n": 2, "side_n": 1}
UTC_OFFSET = {"almeria": -0.18, "biskra": 0.38, "bleiswijk": 0.3, "seville": -0.39}
"""Local solar time minus UTC [h] at each weather site (longitude / 15)."""
GROWER_SHIFT = {"bleiswijk": -6.0}
"""A Dutch grower in November airs at lower temperatures [K] than the defaults (a house that
never reaches 22 °C would never be opened)."""


def twonode_module():
    """tests/twonode.py, loaded from the source tree (an offline tool: needs the checkout)."""
    path = Path(__file__).resolve().parents[2] / "tests" / "twonode.py"
    if not path.exists():
        raise FileNotFoundError(f"{path}: the two-node generator lives in the source tree's tests/")
    spec = importlib.util.spec_from_file_location("twonode", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def generate(run: Run, path: Path) -> Path:
    """Write the kit CSV of ``run`` to ``path`` (and, for the simulator, its truth files)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if run.generator == "twonode":
        twonode_module().write_kit_csv(str(path), "house", start=run.start, days=run.days,
                                       seed=run.seed)
        return path
    plant = PRESETS["almeria"]
    if run in OTHER:
        plant = plant.with_(**OTHER_HOUSE)
    if run.vents == "grower":
        shift = GROWER_SHIFT.get(run.weather, 0.0)
        base = GrowerVents()
        plant = plant.with_(controller=GrowerVents(
            seed=run.seed, utc_offset=UTC_OFFSET[run.weather], cool=base.cool + shift,
            warm=base.warm + shift, hot=base.hot + shift))
    result = simulate(plant, run.weather, run.start, run.days, seed=run.seed)
    result.write(path)
    return path


def part_of(run: Run) -> str:
    """The folder of ``run`` under a corpus: ``train``, ``test``, ``fresh``, ``other``,
    ``hot-dry`` or ``more-test`` (the opt-in runs stay out of ``train/``, whose files the docs
    glob)."""
    return ("test" if run in TEST else "fresh" if run in FRESH else "other" if run in OTHER
            else "hot-dry" if run in HOT_DRY else "more-test" if run in MORE_TEST else "train")


def write_corpus(out: Path, runs: tuple[Run, ...] = TRAIN + TEST + FRESH + OTHER,
                 progress: Callable[..., None] | None = None) -> list[Path]:
    """Every run of ``runs`` under ``out/<part_of(run)>`` (the default leaves the opt-in
    ``HOT_DRY`` and ``MORE_TEST`` out). ``progress(advance=1, description=None)``
    (gateway/cli/progress.py's callback): each run named as it starts, counted when written."""
    progress = progress or (lambda **k: None)
    paths = []
    for run in runs:
        progress(advance=0, description=run.name)
        part = part_of(run)
        paths.append(generate(run, out / part / f"{run.name}.csv"))
        progress(advance=1)
    return paths

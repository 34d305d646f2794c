"""How much of the base model's held-out error is the night sky the kit cannot see.

The kit reads the cloudiness from the daytime radiation (gateway/model/sky.py) and carries it
through the night. Two measurements:

- ``--night``: over the 51 measured Bleiswijk days, the night-time sky estimate against the
  measured apparent sky temperature (RMSE, bias) and the correlation of the estimate, and of
  other kit readings, with the measured sky depression T_sky − T_out at night.
- the diagnosis's base on effect-free windows of the tuning generators, run twice: with the sky
  the kit estimates, and with the sky the generator was driven by put in the diagnosis's
  drivers (refsim: the window's measured sky; twonode: its own estimate from the daytime
  radiation, tests/twonode.py). The difference is the part of the base's held-out error that
  the sky estimate causes. A study, not a feature: the kit has no sky sensor.

    .venv/bin/python tests/generality/sky_study.py --night                 # seconds
    .venv/bin/python tests/generality/sky_study.py [--generators refsim,twonode] \\
        [--windows autumn,bleiswijk-10-29,...] [--kit-only]   # ~30 s per window and
                                                      # generator, one core
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tests.generality.cases import EXTRA_WINDOWS, Case, case_series, window  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402

WINDOWS = ("autumn", "winter", "summer", *EXTRA_WINDOWS)


def night_table() -> None:
    """Night-time sky estimate against the measured sky of the shipped Bleiswijk weather."""
    from gateway.model import sky
    from tests.generality.windows import BLEISWIJK as BLEISWIJK_SITE
    from training.weather import load_bleiswijk

    w = load_bleiswijk()
    t = w["time"]
    clear = sky.clear_sky(t, *BLEISWIJK_SITE)
    night = clear <= 0.0
    cloud = sky.cloud_fraction(t, w["i_glob"], BLEISWIJK_SITE, 300.0)
    est = sky.sky_temperature(w["t_out"], w["rh_out"], cloud)
    depression = w["t_sky"] - w["t_out"]
    ok = night & np.isfinite(est) & np.isfinite(w["t_sky"])
    err = est[ok] - w["t_sky"][ok]
    print(f"{ok.sum()} night rows of 5 min: sky estimate RMSE {np.sqrt(np.mean(err ** 2)):.2f} K, "
          f"bias {err.mean():+.2f} K; measured depression T_sky - T_out "
          f"{depression[ok].mean():+.1f} ± {depression[ok].std():.1f} K")
    sec = t.astype("datetime64[s]").astype(np.int64).astype(float)
    cooling = w["t_out"] - np.interp(sec - 3 * 3600.0, sec, w["t_out"])
    print("| kit quantity at night | Pearson r with the measured T_sky - T_out |\n| --- | --- |")
    for name, v in (("cloud fraction the kit carries (sky.py)", cloud),
                    ("T_out change over the last 3 h", cooling),
                    ("the same / (1 + wind)", cooling / (1.0 + w["wind"])),
                    ("RH_out", w["rh_out"]), ("wind", w["wind"])):
        m = ok & np.isfinite(v)
        print(f"| {name} | {np.corrcoef(v[m], depression[m])[0, 1]:+.2f} |")
    # the kit's sky error where the cloud is read (r = 0) and where it is carried (r > 0), all
    # rows (the spread the base's sky weights used, removed after 8bdfc66; docs/effects.md)
    _, r, _ = sky.carried_cloud(t, np.maximum(w["i_glob"], 0.0), BLEISWIJK_SITE, 300.0)
    err_all = est - w["t_sky"]
    for label, m in (("read (r = 0)", r == 0.0), ("carried (r > 0)", r > 0.0)):
        m = m & np.isfinite(err_all)
        print(f"sky error where the cloud is {label}: {m.sum()} rows, std {err_all[m].std():.2f} K")


def driving_sky(generator: str, win) -> np.ndarray:
    """The sky temperature [°C] the generator was driven by, at the window's rows."""
    if generator == "twonode":
        from tests import twonode

        return twonode.sky_temperature(win.twonode_weather(), (win.latitude, win.longitude))[0]
    return win.t_sky  # refsim and the held-out generator take the window's (measured) sky


@contextmanager
def generator_sky(generator: str, win):
    """The diagnosis's drivers with the generator's sky in place of the kit's estimate."""
    import gateway.diagnose.search as search

    own = search.drivers
    sec = win.time.astype("datetime64[s]").astype(np.int64).astype(float)
    t_sky = driving_sky(generator, win)

    def with_sky(series, gh):
        x = own(series, gh)
        at = series.time.astype("datetime64[s]").astype(np.int64).astype(float)
        x["t_sky"] = np.interp(at, sec, t_sky)
        return x

    search.drivers = with_sky
    try:
        yield
    finally:
        search.drivers = own


def base_run(generator: str, name: str, sky_of_generator: bool) -> tuple[float, list[str], list[str]]:
    """(base held-out free-run MAE [K], findings, optional parts kept) of one effect-free case."""
    from gateway.diagnose import diagnose

    with tempfile.TemporaryDirectory() as tmp:
        _, gh, model, series = case_series(Case("diagnose", generator, name, "none"), Path(tmp))
        if sky_of_generator:
            with generator_sky(generator, window(name)):
                d = diagnose(series, gh, model)
        else:
            d = diagnose(series, gh, model)
    r = d.measured[d.split_index:] - d.pred_before["free_run"]
    kept = [s["structure"] for s in d.structure if s["kept"] and s["structure"] != "base"]
    return float(np.nanmean(np.abs(r))), [f.effect.name for f in d.findings], kept


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--night", action="store_true", help="only the night-time sky table")
    ap.add_argument("--generators", default="refsim,twonode",
                    help="never the held-out one (default: refsim,twonode)")
    ap.add_argument("--windows", default=",".join(WINDOWS))
    ap.add_argument("--kit-only", action="store_true",
                    help="only the kit's sky (the generator's-sky column is left out: half the time)")
    a = ap.parse_args(argv)
    if a.night:
        night_table()
        return 0
    gens = a.generators.split(",")
    if set(gens) & set(HELD_OUT):
        ap.error(f"{', '.join(HELD_OUT)} is held out: not studied")
    print("| generator | window | base MAE, kit sky [K] | base MAE, generator's sky [K] | "
          "findings (kit sky / generator's sky) | parts kept (kit sky / generator's sky) |")
    print("| --- " * 6 + "|")
    for g in gens:
        for name in a.windows.split(","):
            kit = base_run(g, name, False)
            own = (float("nan"), ["-"], ["-"]) if a.kit_only else base_run(g, name, True)
            print(f"| {g} | {name} | {kit[0]:.3f} | {own[0]:.3f} | "
                  f"{', '.join(kit[1]) or 'none'} / {', '.join(own[1]) or 'none'} | "
                  f"{', '.join(kit[2]) or '-'} / {', '.join(own[2]) or '-'} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

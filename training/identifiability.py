"""The identifiability dataset of thesis §III.4.2.1.2 (table 4), rebuilt on real weather.

Two days (2880 one-minute samples) of the shipped Bleiswijk weather, scaled towards a Biskra
winter (radiation × 1.4, temperature + 3 °C), drive the ``prototype`` model with the assumed
parameters of table 4; the simulated inside temperature is the target a calibrator must
recover the parameters from. ``python -m training identifiability --out FILE`` rebuilds
``training/data/identifiability_prototype_2days.csv``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gateway.greenhouse import load_greenhouse
from gateway.kitcsv import write_kit_csv
from gateway.model import build_model
from gateway.model import psychrometrics as psy
from gateway.model.drivers import prepare_drivers
from gateway.series import Series
from training.weather import load_bleiswijk, to_minutes

ASSUMED = {"c_solar": 5.8e-5, "c_cnv_cnd": 5.3e-4, "c_loss": 1.7e-4, "c_thermal": 2.2e-5}
"""Assumed parameter values of table 4."""
DATASET = Path(__file__).parent / "data" / "identifiability_prototype_2days.csv"
FIRST_DAY = 0  # 2009-10-20 (sunny, 8.8 MJ m-2) and 2009-10-21 (mixed, 6.4 MJ m-2)


def build(first_day: int = FIRST_DAY, days: int = 2) -> Series:
    """Weather slice plus the prototype's simulated inside temperature and humidity."""
    w = to_minutes(load_bleiswijk())
    a = first_day * 1440 + 60  # the file starts at 23:00 UTC; begin at midnight UTC
    b = a + days * 1440
    cols = {
        "t_out": w["t_out"][a:b] + 3.0,
        "rh_out": w["rh_out"][a:b],
        "i_glob": w["i_glob"][a:b] * 1.4,
        "wind": w["wind"][a:b],
    }
    n = b - a
    cols["t_in"] = np.full(n, cols["t_out"][0])
    cols["rh_in"] = np.full(n, 60.0)
    gh = load_greenhouse("biskra-prototype")
    model = build_model("prototype", gh)
    series = Series(w["time"][a:b], 60.0, cols, source="identifiability")
    theta = np.array([ASSUMED[n] for n in model.names])
    t_in = model.free_run(theta[None, :], prepare_drivers(series, gh), gh, 60.0)[0]
    cols["t_in"] = t_in
    # Inside air holds the outside vapour: RH follows from the simulated temperature.
    p_w = psy.vapour_pressure(cols["t_out"], cols["rh_out"])
    cols["rh_in"] = np.clip(psy.relative_humidity(t_in, p_w), 0.0, 100.0)
    return series


def write(path: Path = DATASET) -> Path:
    s = build()
    return write_kit_csv(path, s.time, s.columns, digits=12)


if __name__ == "__main__":
    print(write())

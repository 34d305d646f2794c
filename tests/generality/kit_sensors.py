"""Kit sensor readings for the third generator (tests/generality/vanthoor.py), written apart from
training/simulate/sensors.py (same datasheet figures, own code).

- DHT22 (inside and outside air): fixed bias N(0, 0.25 K) within ±0.5 K and N(0, 1.5 %RH)
  within ±3 %RH, reading noise 0.08 K / 0.3 %RH, 0.1 resolution, 0.3 % of reads lost
  (temperature and humidity together). The inside RH is read at the sensor body's temperature
  (a sun-heated body reads drier).
- BPW34 pyranometer: gain error N(0, 2.3 %), noise 1 W m-2, 1 W m-2 steps, never negative.
- DC-motor anemometer: gain error N(0, 3 %), 0.47 m s-1 steps.

One reading per 5 minutes (the kit's rows), instantaneous.
"""

from __future__ import annotations

import numpy as np

ROW = 5  # minutes per kit row (the truth is on a 60-s grid)


def _saturation(t: np.ndarray) -> np.ndarray:
    """[Pa], Magnus over water (Alduchov & Eskridge 1996)."""
    return 610.94 * np.exp(17.625 * t / (t + 243.04))


def _dht22(rng: np.random.Generator, t: np.ndarray, rh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    bias_t = float(np.clip(rng.normal(0.0, 0.25), -0.5, 0.5))
    bias_rh = float(np.clip(rng.normal(0.0, 1.5), -3.0, 3.0))
    t_read = np.round(t + bias_t + rng.normal(0.0, 0.08, t.shape), 1)
    rh_read = np.round(np.clip(rh + bias_rh + rng.normal(0.0, 0.3, rh.shape), 0.0, 99.9), 1)
    lost = rng.random(t.shape) < 0.003
    t_read[lost] = np.nan
    rh_read[lost] = np.nan
    return t_read, rh_read


def kit_columns(t_body: np.ndarray, vp_in: np.ndarray, weather, seed: int,
                drift: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Kit columns at 5-minute rows from the truth on the window's 60-s grid.

    ``t_body`` inside sensor body [°C], ``vp_in`` inside vapour pressure [Pa], ``weather`` the
    :class:`~tests.generality.windows.Window`, ``drift`` [K] added to the inside reading only.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7907]))
    rows = np.arange(0, len(t_body), ROW)
    body = t_body[rows]
    rh_in = 100.0 * vp_in[rows] / _saturation(body)
    t_in, rh_in = _dht22(rng, body + (0.0 if drift is None else drift[rows]), rh_in)
    t_out, rh_out = _dht22(rng, weather.t_out[rows], weather.rh_out[rows])
    gain_i, gain_u = 1.0 + rng.normal(0.0, 0.023), 1.0 + rng.normal(0.0, 0.03)
    i_glob = np.maximum(np.round(gain_i * weather.i_glob[rows] + rng.normal(0.0, 1.0, len(rows))), 0.0)
    wind = np.round(gain_u * weather.wind[rows] / 0.47) * 0.47
    return {"t_in": t_in, "rh_in": rh_in, "t_out": t_out, "rh_out": rh_out, "i_glob": i_glob,
            "wind": np.round(wind, 2)}

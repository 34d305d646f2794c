"""Sensor models: what the kit's and the professional sensors report from the true values.

Each sensor has a fixed calibration error drawn once per run (bias or gain), white noise per
reading, quantisation to its resolution, a physical range, and for the DHT22 occasional read
failures (an empty CSV cell, for temperature and RH together). All draws come from the run's
seeded generator.

References (datasheets)
-----------------------
- Aosong DHT22/AM2302: ±0.5 °C, ±2 % RH (±5 % at extremes), resolution 0.1 °C / 0.1 % RH.
- Vishay BPW34 photodiode pyranometer (Čekon et al. 2016, thesis §II.2.2): 2.3 % error,
  9.6 W m-2 sensitiveness.
- DC-motor anemometer (thesis §II.2.2): 0.47 m s-1 steps.
- Campbell Scientific HC2S3: ±0.1 °C, ±0.8 % RH; Hukseflux LP02: < ±1 % (thesis table 1);
  Campbell 108 soil probe ±0.7 °C; Vector A100L2 < 2 %.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class SensorSpec:
    """One sensor channel.

    ``bias_sd`` [unit] and ``bias_max`` [unit] of the fixed offset; ``gain_sd`` [-] of the fixed
    relative gain error; ``noise_sd`` [unit] per reading; ``resolution`` [unit] (0 = none);
    ``lower``/``upper`` clip range [unit]; ``fail_rate`` [-] probability that a reading is lost.
    """

    model: str
    bias_sd: float = 0.0
    bias_max: float = np.inf
    gain_sd: float = 0.0
    noise_sd: float = 0.0
    resolution: float = 0.0
    lower: float = -np.inf
    upper: float = np.inf
    fail_rate: float = 0.0


DHT22_T = SensorSpec("DHT22", bias_sd=0.25, bias_max=0.5, noise_sd=0.08, resolution=0.1,
                     lower=-40.0, upper=80.0, fail_rate=0.003)
DHT22_RH = SensorSpec("DHT22", bias_sd=1.5, bias_max=5.0, noise_sd=0.3, resolution=0.1,
                      lower=0.0, upper=99.9)
BPW34 = SensorSpec("BPW34", gain_sd=0.023, noise_sd=1.0, resolution=9.6, lower=0.0, upper=1400.0)
DC_ANEMOMETER = SensorSpec("DC-motor anemometer", gain_sd=0.03, resolution=0.47, lower=0.0,
                           upper=40.0)
RAIN = SensorSpec("MH-RD")
HC2S3_T = SensorSpec("HC2S3", bias_sd=0.05, bias_max=0.1, noise_sd=0.02, resolution=0.01,
                     lower=-40.0, upper=60.0)
HC2S3_RH = SensorSpec("HC2S3", bias_sd=0.4, bias_max=0.8, noise_sd=0.1, resolution=0.1,
                      lower=0.0, upper=100.0)
LP02 = SensorSpec("LP02", gain_sd=0.005, noise_sd=0.5, resolution=0.1, lower=0.0, upper=2000.0)
A100L2 = SensorSpec("A100L2", gain_sd=0.01, noise_sd=0.02, resolution=0.01, lower=0.0,
                    upper=75.0)
CS108 = SensorSpec("108", bias_sd=0.3, bias_max=0.7, noise_sd=0.02, resolution=0.01,
                   lower=-5.0, upper=95.0)
VENT_POSITION = SensorSpec("vent position feedback", resolution=0.1, lower=0.0, upper=100.0)
LAI_ESTIMATE = SensorSpec("LAI from crop records", gain_sd=0.05, resolution=0.01, lower=0.0,
                          upper=15.0)

KIT_SENSORS = {
    "t_in": DHT22_T, "rh_in": DHT22_RH, "t_out": DHT22_T, "rh_out": DHT22_RH,
    "i_glob": BPW34, "wind": DC_ANEMOMETER, "rain": RAIN,
}
PRO_SENSORS = {
    "t_in": HC2S3_T, "rh_in": HC2S3_RH, "t_out": HC2S3_T, "rh_out": HC2S3_RH,
    "i_glob": LP02, "wind": A100L2, "i_in": LP02, "t_soil": CS108,
    "vent_roof": VENT_POSITION, "vent_side": VENT_POSITION, "lai": LAI_ESTIMATE, "rain": RAIN,
}


def sensor_set(columns: tuple[str, ...]) -> dict[str, SensorSpec]:
    """The sensor of each column: the kit's low-cost set when there is no ``i_in`` column."""
    table = PRO_SENSORS if "i_in" in columns else KIT_SENSORS
    return {c: table[c] for c in columns}


@dataclass(frozen=True)
class Calibration:
    """The errors drawn for one sensor in one run (written to the truth JSON)."""

    model: str
    bias: float
    gain: float

    def to_dict(self) -> dict:
        """Plain dict."""
        return asdict(self)


def draw_calibration(spec: SensorSpec, rng: np.random.Generator) -> Calibration:
    """Fixed bias [unit] and gain [-] of one sensor, drawn once per run."""
    bias = float(np.clip(rng.normal(0.0, spec.bias_sd), -spec.bias_max, spec.bias_max))
    gain = float(1.0 + rng.normal(0.0, spec.gain_sd))
    return Calibration(spec.model, bias, gain)


def measure(true: np.ndarray, spec: SensorSpec, cal: Calibration,
            rng: np.random.Generator) -> np.ndarray:
    """Readings of ``true`` values: gain and bias, noise, range clip, quantisation, failures."""
    x = cal.gain * np.asarray(true, dtype=float) + cal.bias
    if spec.noise_sd:
        x = x + rng.normal(0.0, spec.noise_sd, x.shape)
    x = np.clip(x, spec.lower, spec.upper)
    if spec.resolution:
        x = np.round(x / spec.resolution) * spec.resolution
        x = np.round(x, 6)  # keep 0.1 steps printable as 0.1, not 0.30000000000000004
    if spec.fail_rate:
        x[rng.random(x.shape) < spec.fail_rate] = np.nan
    return x

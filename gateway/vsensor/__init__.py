"""The virtual ventilation sensor (thesis §IV.3): a PCA-NARX network run with onnxruntime.

- ``features``: what the sensor reads, III.32, the physical range of the flow;
- ``adaptive``: the adaptive model run with and without the vent signal;
- ``loop``: the NARX closed loop (batch); ``runtime``: :class:`VentSensor`, one step a minute;
- ``batch``: the sensor over a kit CSV and its score; ``models``: the shipped models.

Nothing here imports scikit-learn or anything under ``training/``.
"""

from gateway.vsensor.model_info import ModelMismatch
from gateway.vsensor.runtime import SensorCounts, VentEstimate, VentSensor, fluxes_now

__all__ = ["ModelMismatch", "SensorCounts", "VentEstimate", "VentSensor", "fluxes_now"]

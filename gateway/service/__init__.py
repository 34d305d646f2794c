"""The live gateway service (``python -m gateway run --config gateway.toml``), docs/gateway.md.

kit → ingest (gateway/ingest) → store → per greenhouse: minute QC → online estimator, forecasts,
fluxes (pipeline.py) → outbox (gateway/store/outbox.py) → Zenoh (gateway/publish).

- :mod:`gateway.service.config`: the TOML config, validated with errors that name the key;
- :mod:`gateway.service.settings`: the settings it yields, one dataclass per section, with
  the defaults a config without the key gets;
- :mod:`gateway.service.clock`: the gateway clock (wall time, or scaled for tests and demos);
- :mod:`gateway.service.minutes`: a greenhouse's QC'd minutes from the store, and when one is due;
- :mod:`gateway.service.pipeline`: the per-greenhouse estimator step, saved with its state;
- :mod:`gateway.service.producers`: stored rows → outbox messages (measurements, estimates,
  devices, status), each behind a cursor moved in the same transaction;
- :mod:`gateway.service.diagnosis`: the daily diagnosis in a subprocess and its findings;
- :mod:`gateway.service.run`: the asyncio service that ties them together.
"""

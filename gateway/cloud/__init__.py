"""The cloud side (``python -m gateway subscribe``): a Zenoh subscriber and its store.

:mod:`gateway.cloud.store` (the :class:`CloudStore` interface and its SQLite default),
:mod:`gateway.cloud.postgres` (the PostgreSQL store for a fleet) and
:mod:`gateway.cloud.subscriber` (the advanced subscriber, kit CSV export). docs/cloud.md,
docs/fleet.md.
"""

"""The cloud side (``python -m gateway subscribe``): a Zenoh subscriber and its store.

:mod:`gateway.cloud.store` (the :class:`CloudStore` interface and its SQLite default) and
:mod:`gateway.cloud.subscriber` (the advanced subscriber, kit CSV export). docs/cloud.md.
"""

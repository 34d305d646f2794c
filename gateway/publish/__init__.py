"""Publishing over Zenoh (docs/cloud.md): the key space (keyspace.py), FIWARE-shaped payloads
(payloads.py) checked offline against the shipped schemas (validate.py, schemas/), the Zenoh
config (zconfig.py), the store-and-forward publisher (publisher.py) and the history queryable
(history.py)."""

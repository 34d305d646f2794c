"""Zenoh networking and security shared by the router, the gateway and the subscriber.

certs (the fleet PKI), zenohcfg (TLS, endpoints → Zenoh config entries), acl (access control),
routerconf and router (``python -m gateway router``). docs/fleet.md describes the whole.
"""

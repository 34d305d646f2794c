"""Ingest: receive packets (UDP, serial), validate them, store them durably, then acknowledge."""

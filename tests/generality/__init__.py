"""Generality study: independent greenhouse generators on several weather windows (issue 10)."""

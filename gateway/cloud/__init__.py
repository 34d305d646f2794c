"""Cloud-side storage of what the fleet publishes (PostgreSQL; SQLite stays the embedded default)."""

"""``python -m gateway ingest ...``: the ingest service (UDP/serial → SQLite), see
docs/wire-format.md. The arguments are those of ``python -m gateway.ingest.service``."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:
    sub.add_parser(
        "ingest",
        help="run the ingest service: kit packets over UDP/serial into SQLite",
        description="Run the ingest service. Arguments are passed on to "
        "'python -m gateway.ingest.service' (see its --help): --db, --keys, --listen HOST:PORT, "
        "--serial URL, --retention-days, --max-db-mb, --batch-delay.",
    )
    # Listed here for the command overview; gateway.cli.main hands 'ingest ...' to the service.

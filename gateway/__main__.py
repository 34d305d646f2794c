"""``python -m gateway <command>``: see gateway/cli/."""

from gateway.cli import main

raise SystemExit(main())

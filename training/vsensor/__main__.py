"""``python -m training.vsensor``: see training/vsensor/cli.py."""

from training.vsensor.cli import main

raise SystemExit(main())

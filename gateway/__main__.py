"""``python -m gateway <command>``: see gateway/cli/."""

import os
import sys

from gateway.cli import main

try:
    code = main()
except BrokenPipeError:  # the reader went away (`router --check | head`): exit, no traceback
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's own flush at exit
    code = 1
raise SystemExit(code)

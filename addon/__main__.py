"""`python -m addon <verb> ...`: the command line (see `addon.cli`), from this project's venv."""

import sys

from .cli import main

sys.exit(main(sys.argv[1:]))

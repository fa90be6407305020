"""`python -m geofeat` runs the command line (as `geofeat` and `python -m geofeat.cli` do)."""

import sys

from .cli import main

sys.exit(main())

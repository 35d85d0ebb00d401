"""`python -m tryon.cli ...` runs the `tryon` command."""

import sys

from tryon.cli import main

sys.exit(main())

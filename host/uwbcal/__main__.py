"""`python -m uwbcal` runs the command line."""

import sys

from uwbcal.cli import main

sys.exit(main())

"""``python -m uwbcal.evk1000``: one emulated EVK1000 station (see uwbcal.evk1000.station)."""

import sys

from uwbcal.evk1000.station import main

sys.exit(main())

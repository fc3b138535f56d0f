"""``python -m lightcurve_gp.sweep CONFIG --grid KEY=V1,V2,... --seeds N``."""

import sys

from .cli import main

sys.exit(main())

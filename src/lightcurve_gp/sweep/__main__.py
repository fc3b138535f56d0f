"""``python -m lightcurve_gp.sweep CONFIG --grid KEY=V1,V2,... --seeds N``."""

from ..cli import exit_process
from .cli import main

exit_process(main())

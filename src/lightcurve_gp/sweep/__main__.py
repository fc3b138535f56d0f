"""``python -m lightcurve_gp.sweep CONFIG --grid KEY=V1,V2,... --seeds N``."""

from lightcurve_gp.commands.common import exit_process
from lightcurve_gp.sweep.cli import main

exit_process(main())

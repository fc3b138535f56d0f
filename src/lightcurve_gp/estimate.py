"""``python -m lightcurve_gp.estimate``: the command of :mod:`lightcurve_gp.commands.estimate`."""

from lightcurve_gp.commands.common import exit_process
from lightcurve_gp.commands.estimate import main

if __name__ == "__main__":
    exit_process(main())

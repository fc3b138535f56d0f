"""``python -m lightcurve_gp.invert``: the command of :mod:`lightcurve_gp.commands.invert`."""

from lightcurve_gp.commands.common import exit_process
from lightcurve_gp.commands.invert import main

if __name__ == "__main__":
    exit_process(main())

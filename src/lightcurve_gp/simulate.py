"""``python -m lightcurve_gp.simulate``: the command of :mod:`lightcurve_gp.commands.simulate`."""

from lightcurve_gp.commands.common import exit_process
from lightcurve_gp.commands.simulate import main

if __name__ == "__main__":
    exit_process(main())

"""``python -m lightcurve_gp.train``: the command of :mod:`lightcurve_gp.commands.train`."""

from lightcurve_gp.commands.common import exit_process
from lightcurve_gp.commands.train import main

if __name__ == "__main__":
    exit_process(main())

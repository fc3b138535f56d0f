"""``python -m lightcurve_gp.simulate``, i.e. ``lightcurve-gp simulate`` (:func:`lightcurve_gp.__main__.run`)."""
import sys

from lightcurve_gp.__main__ import run

if __name__ == "__main__":
    run(["simulate", *sys.argv[1:]], command_prog="python -m lightcurve_gp.simulate")

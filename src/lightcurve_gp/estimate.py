"""``python -m lightcurve_gp.estimate``, i.e. ``lightcurve-gp estimate`` (:func:`lightcurve_gp.__main__.run`)."""
import sys

from lightcurve_gp.__main__ import run

if __name__ == "__main__":
    run(["estimate", *sys.argv[1:]], command_prog="python -m lightcurve_gp.estimate")

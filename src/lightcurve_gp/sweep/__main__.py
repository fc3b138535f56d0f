"""``python -m lightcurve_gp.sweep``, i.e. ``lightcurve-gp sweep`` (:func:`lightcurve_gp.__main__.run`)."""
import sys

from lightcurve_gp.__main__ import run

if __name__ == "__main__":
    run(["sweep", *sys.argv[1:]], command_prog="python -m lightcurve_gp.sweep")

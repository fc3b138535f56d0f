"""``python -m lightcurve_gp.invert``, i.e. ``lightcurve-gp invert`` (:func:`lightcurve_gp.__main__.run`)."""
import sys

from lightcurve_gp.__main__ import run

if __name__ == "__main__":
    run(["invert", *sys.argv[1:]], command_prog="python -m lightcurve_gp.invert")

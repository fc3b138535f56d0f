"""``python -m lightcurve_gp.train``, i.e. ``lightcurve-gp train`` (:func:`lightcurve_gp.__main__.run`)."""
import sys

from lightcurve_gp.__main__ import run

if __name__ == "__main__":
    run(["train", *sys.argv[1:]], command_prog="python -m lightcurve_gp.train")

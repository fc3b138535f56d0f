"""lightcurve-gp: attitude and spin estimation of space objects from light curves.

Gaussian-process and parametric observation models behind one interface, a torch-vectorised facet renderer
(Ashikhmin–Shirley BRDF), torque-free dynamics, a batched USQUE unscented Kalman filter, batch MAP and global
inversion. The layers and where each concept lives: ``docs/design.md``; a config loads with
:func:`lightcurve_gp.config.load.load_config`. The package itself imports nothing but its version (from the
installed distribution's metadata), so that importing it stays free of torch and the command entry points can turn a
Ctrl-C during their imports into one line.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lightcurve-gp")  # the installed distribution's, so it cannot drift from pyproject.toml
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "unknown (not installed)"

__all__ = ["__version__"]

"""lightcurve-gp: attitude and spin estimation of space objects from light curves.

Gaussian-process and parametric observation models behind one interface, a torch-vectorised facet renderer
(Ashikhmin–Shirley BRDF), torque-free dynamics, a batched USQUE unscented Kalman filter, batch MAP and global
inversion. The layers and where each concept lives: ``docs/design.md``; a config loads with
:func:`lightcurve_gp.config.load.load_config`. The package itself imports nothing, so that importing it stays free of
torch and the command entry points can turn a Ctrl-C during their imports into one line.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]

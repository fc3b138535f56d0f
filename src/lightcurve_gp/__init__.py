"""lightcurve-gp: attitude estimation of space objects from light curves.

Gaussian-process and parametric observation models behind one interface, a torch-vectorised facet
renderer (Ashikhmin–Shirley BRDF), torque-free dynamics and a batched USQUE unscented Kalman filter.
"""

from lightcurve_gp.config.load import Config, ConfigError, load_config

__version__ = "0.1.0"

__all__ = ["Config", "ConfigError", "load_config", "__version__"]

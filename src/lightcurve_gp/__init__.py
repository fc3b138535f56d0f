"""lightcurve-gp: attitude and spin estimation of space objects from light curves.

Gaussian-process and parametric observation models behind one interface, a torch-vectorised facet renderer
(Ashikhmin–Shirley BRDF), torque-free dynamics, a batched USQUE unscented Kalman filter, batch MAP and global
inversion. The layers and where each concept lives: ``docs/design.md``.

``Config``, ``ConfigError`` and ``load_config`` (from :mod:`lightcurve_gp.config.load`) are importable from here; they
load on first use, so that importing the package stays free of torch until something needs it and the command
entry points can turn a Ctrl-C during their imports into one line.
"""

__version__ = "0.1.0"

__all__ = ["Config", "ConfigError", "load_config", "__version__"]

_CONFIG_NAMES = ("Config", "ConfigError", "load_config")


def __getattr__(name: str):
    # module-level __getattr__ (PEP 562): the config layer imports torch, which takes seconds
    if name in _CONFIG_NAMES:
        from lightcurve_gp.config import load

        return getattr(load, name)
    raise AttributeError(f"module 'lightcurve_gp' has no attribute {name!r}")

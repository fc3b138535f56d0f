"""Where the commands write under ``--out`` (``OUT``): one folder per kind of run, none inside another::

    OUT/<name>/                             train: model.pt, metrics.json, config.yaml, two figures
    OUT/models/<model-key>/                 the model store: each model train or sweep made, by its key
    OUT/cache/                              training sets, by content hash
    OUT/estimates/<name>/rho<rho>/          estimate on the config's simulated scenario
    OUT/estimates/<name>/light_curve_<stem>/  estimate --light-curve FILE
    OUT/estimates/<name>/invert_<stem>/       invert --light-curve FILE
    OUT/sweeps/<name>/cases/                sweep: one file per finished case (resumable)
    OUT/sweeps/<name>/sweep/<sweep-id>/     sweep: its tables

So ``train --force`` replaces a training run however many estimates and sweeps used its model, and a sweep finds
the model ``train`` made (same settings, same key) in the store instead of training it again. A config may not be
named like one of the shared folders (:data:`SHARED_FOLDERS`).
"""

from __future__ import annotations

from pathlib import Path

from lightcurve_gp.commands.common import UserError

__all__ = ["SHARED_FOLDERS", "check_run_name", "train_folder", "model_store", "data_cache", "estimate_folder",
           "light_curve_folder", "invert_folder", "sweeps_root"]

#: the folders of OUT that are not one training run
SHARED_FOLDERS = ("models", "cache", "estimates", "sweeps")


def check_run_name(name: str) -> None:
    """Refuse a config name that is one of :data:`SHARED_FOLDERS` (its training run would land in it)."""
    if name in SHARED_FOLDERS:
        raise UserError(f"name: {name!r} is the name of a shared folder of --out ({', '.join(SHARED_FOLDERS)}); "
                        f"choose another (--set name=...)")


def train_folder(out: Path, name: str) -> Path:
    """``OUT/<name>``: the training run of config ``name``."""
    return Path(out) / name


def model_store(out: Path) -> Path:
    """``OUT/models``: the model store (:mod:`lightcurve_gp.training.store`) of ``train`` and ``sweep``."""
    return Path(out) / "models"


def data_cache(out: Path) -> Path:
    """``OUT/cache``: the training-set cache (the default of ``--cache``)."""
    return Path(out) / "cache"


def estimate_folder(out: Path, name: str, rho_true: float) -> Path:
    """``OUT/estimates/<name>/rho<rho_true>``: ``estimate`` on the simulated scenario of config ``name``."""
    return Path(out) / "estimates" / name / f"rho{rho_true:g}"


def light_curve_folder(out: Path, name: str, light_curve: Path) -> Path:
    """``OUT/estimates/<name>/light_curve_<stem>``: ``estimate --light-curve`` of a file with config ``name``."""
    return Path(out) / "estimates" / name / f"light_curve_{Path(light_curve).stem}"


def invert_folder(out: Path, name: str, light_curve: Path) -> Path:
    """``OUT/estimates/<name>/invert_<stem>``: ``invert --light-curve`` of a file with config ``name``."""
    return Path(out) / "estimates" / name / f"invert_{Path(light_curve).stem}"


def sweeps_root(out: Path) -> Path:
    """``OUT/sweeps``: the ``out`` of :func:`~lightcurve_gp.sweep.runner.run_sweep` (it adds ``<name>/``)."""
    return Path(out) / "sweeps"

"""The trained model of a config for the experiments: from the model store ``runs/models`` (trained when missing)."""

from __future__ import annotations

from pathlib import Path

from lightcurve_gp.training.store import get_or_train

__all__ = ["trained_model"]


def trained_model(cfg, runs: Path):
    """The model of ``cfg`` from the model store ``runs/models`` (trained there when missing)."""
    return get_or_train(cfg, runs / "models", cache_dir=runs / "cache")[0]

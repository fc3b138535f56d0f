"""The models a sweep needs: one GP per distinct model key, from the model store (trained once, reused)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from .grid import Case

__all__ = ["model_path", "ensure_models"]


def model_path(root: Path, model_hash: str) -> Path:
    """Where the model of ``model_hash`` lives in the store ``<root>/models`` of a sweep root."""
    return Path(root) / "models" / model_hash / "model.pt"


def ensure_models(cases: Sequence[Case], root: Path, cache_dir: Path,
                  progress: bool = True) -> dict[str, str | None]:
    """Get every model the cases need from the model store ``root/models``
    (:func:`lightcurve_gp.model_store.get_or_train`, in the config's dtype), training the missing ones.

    Returns ``{model_hash: error or None}``; a failed training is reported, not raised, so that the cases that
    need it fail with its error and the others go on.
    """
    from ..model_store import get_or_train

    errors: dict[str, str | None] = {}
    wanted = {c.model_hash: c.config for c in cases if c.model_hash is not None}
    for model_hash, cfg in wanted.items():
        try:
            get_or_train(cfg, Path(root) / "models", cache_dir=cache_dir, progress=progress)
            errors[model_hash] = None
        except Exception as exc:  # recorded on every case that needs this model
            errors[model_hash] = f"model training failed: {type(exc).__name__}: {exc}"
    return errors

"""What a trained model depends on, and its key in the model store.

The key (:func:`model_key`) hashes the ``geometry`` (not for a ``body_geometry`` GP), ``shape``, ``surface``,
``data`` and ``model`` sections with the mesh file's *content* hash in place of its path
(:func:`~lightcurve_gp.config.hashing.content_hash`), the dtype and :data:`STORE_FORMAT`; the run name is not part
of it. A model file carries :func:`model_record`, from which :mod:`lightcurve_gp.training.store` tells whether it
was trained with a config's settings.
"""

from __future__ import annotations

from typing import Any

from lightcurve_gp.config.hashing import config_to_dict, content_dict, content_hash
from lightcurve_gp.config.schema import Config

__all__ = ["MODEL_SECTIONS", "IGNORED_KEYS", "STORE_FORMAT", "model_sections", "model_key", "model_record"]

#: config sections a trained model depends on (with the dtype)
MODEL_SECTIONS = ("geometry", "shape", "surface", "data", "model")
#: keys of those sections that do not change the model (only the held-out evaluation written beside it)
IGNORED_KEYS = ("data.heldout_size",)
STORE_FORMAT = 1


def model_sections(cfg: Config) -> tuple[str, ...]:
    """:data:`MODEL_SECTIONS` less ``geometry`` for a ``body_geometry`` GP, which is trained over geometries and
    serves every pass."""
    if cfg.model.inputs == "body_geometry":
        return tuple(s for s in MODEL_SECTIONS if s != "geometry")
    return MODEL_SECTIONS


def model_key(cfg: Config) -> str:
    """16 hex digits: the store key of the model ``cfg`` trains (see the module docstring)."""
    return content_hash(cfg, *model_sections(cfg), extra={"dtype": cfg.dtype, "store_format": STORE_FORMAT})


def model_record(cfg: Config) -> dict[str, Any]:
    """What a model file carries about its training, in ``extra``: the full config, the model key and the
    content dict of :data:`MODEL_SECTIONS` (mesh hash included) that
    :func:`~lightcurve_gp.training.store.training_mismatch` compares."""
    return {"config": config_to_dict(cfg), "model_key": model_key(cfg), "dtype": cfg.dtype,
            "trained_on": content_dict(cfg, *model_sections(cfg))}

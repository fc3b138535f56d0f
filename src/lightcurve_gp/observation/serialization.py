"""One-file model storage: ``save_model`` / ``load_model`` for the GP observation models.

A model file is ``torch.save`` of a plain dict (tensors and python scalars/strings/dicts only, so it loads with
``torch.load(weights_only=True)``)::

    {"format": "lightcurve-gp-model", "format_version": 1, "kind": "exact" | "sparse" | "surface_marginal",
     "config": {...model config section...}, "inputs": {...input map and normalisation...},
     "state": {...hyperparameters and prediction cache...}, "extra": {...caller's metadata...}}

It is written atomically (:func:`lightcurve_gp.files.save_torch_atomic`). Loading a missing, corrupted or
foreign file, or one of another format version, raises :class:`ModelFileError` — never a silently wrong model.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.config.load import ModelConfig
from lightcurve_gp.files import save_torch_atomic
from lightcurve_gp.observation.base import ObservationModel
from lightcurve_gp.observation.exact_gp import ExactGP
from lightcurve_gp.observation.inputs import InputMap
from lightcurve_gp.observation.sparse_gp import SparseGP
from lightcurve_gp.observation.surface_marginal import SurfaceMarginalGP

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "MODEL_KINDS",
    "ModelFileError",
    "build_model",
    "load_model",
    "read_model_file",
    "save_model",
]

FORMAT = "lightcurve-gp-model"
FORMAT_VERSION = 1
MODEL_KINDS: dict[str, type] = {"exact": ExactGP, "sparse": SparseGP, "surface_marginal": SurfaceMarginalGP}


class ModelFileError(ValueError):
    """A model file is missing, unreadable, corrupted, of another format version or inconsistent."""


def build_model(q: Tensor, m_past: Tensor, y: Tensor, cfg: ModelConfig, **kwargs: Any) -> ObservationModel:
    """Train the GP named by ``cfg.kind`` (``exact`` or ``sparse``) on ``q (N, 4)``, ``m_past (N,)``, ``y (N,)``;
    ``kwargs`` go to its ``from_data`` (e.g. ``seed``, ``device``). ``cfg.target: surface_normalised`` trains a
    :class:`SurfaceMarginalGP` (its ``per_attitude`` and ``spread_inducing`` in ``kwargs``)."""
    kind = "surface_marginal" if cfg.target == "surface_normalised" else cfg.kind
    return MODEL_KINDS[kind].from_data(q, m_past, y, cfg, **kwargs)


def save_model(model: ObservationModel, path: str | Path, *, extra: dict[str, Any] | None = None) -> Path:
    """Write ``model`` (an :class:`ExactGP`, :class:`SparseGP` or :class:`SurfaceMarginalGP`) to one file at
    ``path``, atomically.

    ``extra`` is stored as given (plain python types and tensors only), e.g. the full config and data hash.
    The exact GP's full Cholesky factor is not stored (it is recomputed when an exact variance is asked for).
    """
    kind = getattr(model, "kind", None)
    if kind not in MODEL_KINDS or not isinstance(model, MODEL_KINDS[kind]):
        raise TypeError(f"cannot save a {type(model).__name__}: only {', '.join(MODEL_KINDS)} GP models")
    payload = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": kind, "config": dict(model.config),
               "inputs": model.inputs.file_state(), "state": model.file_state(), "extra": dict(extra or {})}
    path = Path(path)
    save_torch_atomic(payload, path)
    return path


def read_model_file(path: str | Path) -> dict[str, Any]:
    """Load and check a model file's header; returns the payload dict (raises :class:`ModelFileError`)."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{path}: no such model file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupted zip, truncated pickle, disallowed types...
        raise ModelFileError(f"{path}: not a readable model file ({type(exc).__name__}: {exc})") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ModelFileError(f"{path}: not a {FORMAT} file")
    version = payload.get("format_version")
    if version != FORMAT_VERSION:
        raise ModelFileError(f"{path}: model file format version {version!r}, this code reads version "
                             f"{FORMAT_VERSION}; retrain the model")
    if payload.get("kind") not in MODEL_KINDS:
        raise ModelFileError(f"{path}: unknown model kind {payload.get('kind')!r}")
    for key in ("config", "inputs", "state", "extra"):
        if not isinstance(payload.get(key), dict):
            raise ModelFileError(f"{path}: missing or malformed section {key!r}")
    return payload


def load_model(path: str | Path) -> ObservationModel:
    """Rebuild the saved model (on CPU, float64; move it with ``.to()``); raises :class:`ModelFileError`."""
    payload = read_model_file(path)
    for name, value in payload["state"].items():
        if isinstance(value, Tensor) and not bool(torch.isfinite(value).all()):
            raise ModelFileError(f"{path}: state tensor {name!r} contains non-finite values")
    try:
        inputs = InputMap.from_file_state(payload["inputs"])
        model = MODEL_KINDS[payload["kind"]].from_file_state(inputs, payload["state"], payload["config"])
    except (KeyError, ValueError, TypeError, AttributeError) as exc:
        raise ModelFileError(f"{path}: inconsistent model file ({type(exc).__name__}: {exc})") from exc
    model.extra = payload["extra"]
    return model

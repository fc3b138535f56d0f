"""Training sets of the GP observation model (paper section 3.2): the generator a config needs, the targets the GP
learns, and the on-disk cache keyed by content hash.

Three generators share the pieces of :mod:`.windows`: the paper's windows over attitudes × ``data.rho_grid``
(:mod:`.windows`), windows rendered over many surfaces for ``data.surfaces`` (:mod:`.surfaces`), and attitudes ×
geometries for ``model.inputs: body_geometry`` (:mod:`.geometry`). :func:`generate_training_set` and
:func:`generate_heldout_set` pick one by the config; :func:`model_targets` maps a set to what the model learns;
:func:`load_or_generate` caches it. The shared names of :mod:`.windows` are re-exported here.
"""

from __future__ import annotations

from dataclasses import replace as _replace
from pathlib import Path

import torch
from torch import Tensor

from lightcurve_gp.config.hashing import content_hash
from lightcurve_gp.config.schema import Config, ModelConfig
from lightcurve_gp.files import save_torch_atomic
from lightcurve_gp.training.geometry import geometry_heldout_set, geometry_training_set
from lightcurve_gp.training.surfaces import generate_surface_heldout_set, generate_surface_training_set
from lightcurve_gp.training.windows import (
    TrainingSet,
    attitude_count,
    drop_duplicate_attitudes,
    initial_attitudes,
    training_rates,
    training_scene,
    window_heldout_set,
    window_samples,
    window_training_set,
)

__all__ = ["TrainingSet", "initial_attitudes", "training_scene", "drop_duplicate_attitudes", "training_rates",
           "window_samples",
           "generate_training_set", "generate_heldout_set", "load_or_generate", "normalised_targets",
           "model_targets", "data_cache_key", "DATA_FORMAT_VERSION", "training_set_size"]

DATA_FORMAT_VERSION = 1


def generate_training_set(cfg: Config, progress: bool | None = None) -> TrainingSet:
    """The training set of ``cfg`` (paper: 3852 attitudes × 5 ρ = 19260 points), on CPU in ``cfg.dtype``: rendered
    over many surfaces with ``data.surfaces`` (:mod:`.surfaces`), over geometries for a ``body_geometry`` GP
    (:mod:`.geometry`), else the paper's windows (:func:`~.windows.window_training_set`)."""
    if cfg.data.surfaces is not None:
        return generate_surface_training_set(cfg, progress=progress)
    if cfg.model.inputs == "body_geometry":
        return geometry_training_set(cfg)
    return window_training_set(cfg, progress=progress)


def generate_heldout_set(cfg: Config) -> TrainingSet:
    """Evaluation data off the training set, from the seed ``data.seed + 1`` (independent of it), by the same
    generator as :func:`generate_training_set`: random attitudes with random ρ (:func:`~.windows.window_heldout_set`),
    one random surface each with ``data.surfaces``, or random geometries for a ``body_geometry`` GP."""
    if cfg.data.surfaces is not None:
        return generate_surface_heldout_set(cfg)
    if cfg.model.inputs == "body_geometry":
        return geometry_heldout_set(cfg)
    return window_heldout_set(cfg)


def training_set_size(cfg: Config) -> tuple[int, int]:
    """``(points of the training set, points the model is conditioned on)`` of ``cfg``, from the config alone,
    before anything is allocated; upper bounds (duplicates and zero-flux windows are dropped later). The
    surface-marginal GP is conditioned on each attitude once (its K surfaces summarised), a ``body_geometry`` GP on
    ``data.num_random`` geometries × ρ, the paper's on attitudes × ρ (twice with ``quaternion_sign: both``)."""
    rhos = len(cfg.data.rho_grid)
    if cfg.data.surfaces is not None:
        attitudes = attitude_count(cfg.data)
        return cfg.data.surfaces.per_attitude * attitudes, attitudes
    if cfg.model.inputs == "body_geometry":
        return cfg.data.num_random * rhos, cfg.data.num_random * rhos
    points = attitude_count(cfg.data) * rhos * (2 if cfg.data.quaternion_sign == "both" else 1)
    return points, points


def normalised_targets(m: Tensor, rho: Tensor, rho_reference: float) -> Tensor:
    """ρ-normalised magnitudes ``m + 2.5 log10(ρ / ρ0)`` ``(N,)``: the magnitude the attitude would have at ``ρ0``.

    Exact for a diffuse-dominated light curve (``c_d ∝ ρ``, paper Eqs. (4), (8)), where ρ only shifts the magnitude.
    """
    if not bool((rho > 0).all()):
        raise ValueError("rho: every training reflectance must be positive to normalise magnitudes")
    return m + 2.5 * torch.log10(rho.to(m) / rho_reference)


def model_targets(ts: TrainingSet, model: ModelConfig) -> TrainingSet:
    """The data a GP of ``model`` learns from ``ts``: unchanged for ``model.target = magnitude`` (the paper);
    for ``rho_normalised``, ``y`` and ``m_past`` (the window mean shifts by the same offset) normalised to
    ``model.rho_reference`` by :func:`normalised_targets`, so the GP sees the reference curve only; for
    ``surface_normalised`` the same with ``rho`` the equivalent reflectance ``ρ (1 − F0) / (1 − F0,0)``
    (:mod:`lightcurve_gp.training.surfaces`)."""
    if model.target == "magnitude":
        return ts
    return _replace(ts, m_past=normalised_targets(ts.m_past, ts.rho, model.rho_reference),
                    y=normalised_targets(ts.y, ts.rho, model.rho_reference))


def data_cache_key(cfg: Config) -> str:
    """Hash of everything that determines the training set: the geometry, shape, surface and data sections with
    the mesh file's content hash in place of its path (:func:`~lightcurve_gp.config.load.content_hash`), the dtype and
    the file format (for ``model.inputs: body_geometry`` the reference range instead of the geometry). Editing a
    mesh in place therefore misses the cache instead of loading stale data."""
    extra = {"format": DATA_FORMAT_VERSION, "dtype": cfg.dtype}
    if cfg.model.inputs == "body_geometry":  # no pass's geometry: the canonical geometries at the reference range
        extra.update(inputs="body_geometry", reference_range_km=cfg.model.reference_range_km)
        return content_hash(cfg, "shape", "surface", "data", extra=extra)
    return content_hash(cfg, "geometry", "shape", "surface", "data", extra=extra)


def load_or_generate(cfg: Config, cache_dir: str | Path = "runs/cache",
                     progress: bool | None = None) -> tuple[TrainingSet, Path, bool]:
    """Load the training set of ``cfg`` from ``cache_dir`` or generate and cache it atomically.

    Returns:
        ``(training_set, path, loaded)`` with ``loaded`` true when the cache was hit.
    """
    path = Path(cache_dir) / f"data-{data_cache_key(cfg)}.pt"
    if path.exists():
        try:
            blob = torch.load(path, weights_only=True)
            if blob.get("format") == DATA_FORMAT_VERSION:
                return TrainingSet(**blob["data"]), path, True
        except Exception:  # an unreadable cache file is regenerated, never trusted
            pass
    ts = generate_training_set(cfg, progress=progress)
    save_torch_atomic({"format": DATA_FORMAT_VERSION, "data": ts.state_dict()}, path)
    return ts, path, False

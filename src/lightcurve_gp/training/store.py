"""The one model store: trained observation models keyed by the hash of everything that changes them.

Layout: ``<root>/<model-key>/`` is a training run folder (``model.pt``, ``metrics.json``, ``config.yaml``),
written atomically by :func:`lightcurve_gp.training.fit.train`; the key is :func:`~lightcurve_gp.training.keys.
model_key` (the run name is not part of it). :func:`get_or_train` is used by sweeps, the experiments and the
benchmarks; ``python -m lightcurve_gp.train`` adds the model it trains with :func:`add_to_store` (so a sweep over
the same settings finds it instead of training it again), records its key, and ``estimate`` checks a model file
against its config with :func:`check_model_matches`.

Model files are opened with :func:`open_model`, which turns anything that is not a lightcurve-gp model file
(a text file, a YAML file renamed ``.pt``, a foreign pickle) into one :class:`ModelFileError` line.
"""

from __future__ import annotations

import os
import shutil
import zipfile
from pathlib import Path
from typing import Any

from lightcurve_gp.config.hashing import content_dict
from lightcurve_gp.config.schema import Config, ConfigError
from lightcurve_gp.config.validate import config_from_dict
from lightcurve_gp.files import RunFolder, file_sha256
from lightcurve_gp.observation.base import ObservationModel
from lightcurve_gp.observation.serialization import ModelFileError, load_model
from lightcurve_gp.training.fit import train
from lightcurve_gp.training.keys import (
    IGNORED_KEYS,
    MODEL_SECTIONS,
    STORE_FORMAT,
    model_key,
    model_record,
    model_sections,
)

__all__ = ["MODEL_SECTIONS", "IGNORED_KEYS", "model_sections", "STORE_FORMAT", "ModelMismatchError", "model_key",
           "model_record", "store_folder", "get_or_train", "add_to_store", "open_model", "model_file_record",
           "training_mismatch", "check_model_matches"]


class ModelMismatchError(ConfigError):
    """A model file was trained with settings other than the run's; the message names the first differing key."""


def store_folder(cfg: Config, root: str | Path) -> Path:
    """``<root>/<model_key(cfg)>``: where the store keeps the model of ``cfg``."""
    return Path(root) / model_key(cfg)


def get_or_train(cfg: Config, root: str | Path, *, cache_dir: str | Path | None = None, progress: bool = False,
                 retrain: bool = False) -> tuple[ObservationModel, Path]:
    """The trained model of ``cfg`` and its file: loaded from the store when present and intact, else (or with
    ``retrain``) trained by :func:`lightcurve_gp.training.fit.train` into ``<root>/<key>/`` (atomically; the training
    data cache is ``cache_dir``, default ``<root>/cache``). A damaged store entry is replaced."""
    folder = store_folder(cfg, root)
    path = folder / "model.pt"
    key = model_key(cfg)
    if path.is_file() and not retrain:
        try:
            model = open_model(path)
            if model.extra.get("model_key") == key:
                return model, path
        except ModelFileError:
            pass  # retrained below
    train(cfg, folder, Path(cache_dir) if cache_dir is not None else Path(root) / "cache", progress=progress,
          force=True)
    return open_model(path), path


def add_to_store(run_dir: str | Path, cfg: Config, root: str | Path) -> Path:
    """Put the finished training run ``run_dir`` of ``cfg`` into the store ``root`` under its key, replacing the
    entry there (atomically): its files hard-linked (copied where a link is not possible), so the model exists once
    on disk and either folder can be removed or replaced without touching the other. Returns the store folder."""
    run_dir = Path(run_dir)
    with RunFolder(store_folder(cfg, root), force=True) as tmp:
        for path in sorted(run_dir.iterdir()):
            if path.is_file():
                try:
                    os.link(path, tmp / path.name)
                except OSError:  # another file system, or links not supported
                    shutil.copy2(path, tmp / path.name)
    return store_folder(cfg, root)


def open_model(path: str | Path) -> ObservationModel:
    """Load a model file; anything that is not a lightcurve-gp model file gives a one-line :class:`ModelFileError`.

    A model file is a PyTorch zip archive; a text or YAML file, a foreign archive or a pickle holding objects a
    model file never contains is refused with ``<path>: not a lightcurve-gp model file (...)`` — never with
    PyTorch's advice about ``weights_only``, which would be wrong for a user.
    """
    path = Path(path)
    if path.is_dir():
        raise ModelFileError(f"{path}: is a folder, not a model file")
    if not path.is_file():
        raise ModelFileError(f"{path}: no such model file")
    try:
        archive = zipfile.is_zipfile(path)
    except OSError as exc:
        raise ModelFileError(f"{path}: cannot read the model file ({exc.strerror})") from None
    if not archive:
        raise ModelFileError(f"{path}: not a lightcurve-gp model file (not a PyTorch archive; train one with "
                             f"python -m lightcurve_gp.train)")
    try:
        return load_model(path)
    except ModelFileError as exc:
        if exc.__cause__ is not None and "weights_only" in str(exc):
            raise ModelFileError(f"{path}: not a lightcurve-gp model file (it holds objects other than tensors "
                                 f"and plain values)") from None
        raise


def _flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for k, v in tree.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: tree}


def _trained_on(model: ObservationModel) -> dict[str, Any] | None:
    extra = getattr(model, "extra", None) or {}
    if "trained_on" in extra:
        return {"dtype": extra.get("dtype"), **extra["trained_on"]}
    if "config" in extra:  # written before the store existed: no mesh hash, compare the paths' settings as given
        try:
            cfg = config_from_dict(extra["config"])
        except ConfigError:
            return None
        if cfg.shape.kind == "mesh":
            return None
        return {"dtype": cfg.dtype, **content_dict(cfg, *MODEL_SECTIONS)}
    return None


def training_mismatch(model: ObservationModel, cfg: Config) -> str | None:
    """``None`` when ``model`` was trained with ``cfg``'s settings, else a one-line description of the first
    differing key (in the order of the config file), e.g. ``data.t_span_past: the model was trained with 10,
    the config says 20``. :data:`IGNORED_KEYS` are not compared."""
    trained = _trained_on(model)
    if trained is None:
        return "the model file does not record the config it was trained with (older format); retrain it"
    mine = _flatten({"dtype": cfg.dtype, **content_dict(cfg, *model_sections(cfg))})
    theirs = _flatten(trained)
    for key in list(mine) + [k for k in theirs if k not in mine]:
        if key in IGNORED_KEYS:
            continue
        if mine.get(key, "<missing>") != theirs.get(key, "<missing>"):
            if key == "shape.mesh_sha256":
                return "shape.mesh_path: the model was trained on another mesh (the files' content hashes differ)"
            return (f"{key}: the model was trained with {theirs.get(key, '<missing>')!r}, the config says "
                    f"{mine.get(key, '<missing>')!r}")
    return None


def check_model_matches(model: ObservationModel, cfg: Config, path: str | Path) -> None:
    """Raise :class:`ModelMismatchError` when :func:`training_mismatch` finds a difference."""
    diff = training_mismatch(model, cfg)
    if diff is not None:
        raise ModelMismatchError(f"--model {path}: {diff}; train a model with this config or pass "
                                 f"--allow-model-mismatch")


def model_file_record(path: str | Path) -> dict[str, str]:
    """``{"model_file": absolute path, "model_sha256": hash}`` for a run's provenance."""
    return {"model_file": str(Path(path).resolve()), "model_sha256": file_sha256(path)}

"""The models a sweep needs: one GP per distinct model key, from the model store (trained once, reused).

The missing ones are trained by one :func:`train_model` task per model on the sweep's executor, all finished
before any case that needs one starts, so no two workers ever train the same model; the cases' workers then load
them from the store.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import torch

from lightcurve_gp.config.hashing import config_to_dict
from lightcurve_gp.config.validate import config_from_dict
from lightcurve_gp.sweep.executors import Executor, SerialExecutor
from lightcurve_gp.sweep.grid import Case
from lightcurve_gp.training.store import get_or_train

__all__ = ["model_path", "train_model", "ensure_models"]


def model_path(store: Path, model_hash: str) -> Path:
    """Where the model of ``model_hash`` lives in the model store ``store``."""
    return Path(store) / model_hash / "model.pt"


def train_model(spec: dict[str, Any]) -> str:
    """Get the model of ``spec["config"]`` (a plain config dict) from the model store ``spec["store"]``, training
    it when missing (:func:`lightcurve_gp.training.store.get_or_train`, in the config's dtype); returns its file.

    The task of one model on an executor, so ``spec`` holds plain values: ``threads`` are the torch threads of the
    worker process (None: leave torch's), ``cache_dir`` the training-data cache, ``progress`` shows training's
    progress.
    """
    if spec.get("threads"):
        torch.set_num_threads(int(spec["threads"]))
    _, path = get_or_train(config_from_dict(spec["config"]), spec["store"], cache_dir=spec["cache_dir"],
                           progress=spec.get("progress", False))
    return str(path)


def ensure_models(cases: Sequence[Case], store: Path, cache_dir: Path, executor: Executor,
                  progress: bool | None = None, threads: int | None = None) -> dict[str, str | None]:
    """Get every model the cases need from the model store ``store``: one :func:`train_model` task per distinct
    model on ``executor`` (a model already in the store, trained by ``train`` or an earlier sweep, is only loaded
    and checked).

    ``threads``: torch threads of a worker process (None: leave torch's, as in this process). Returns
    ``{model_hash: error or None}``; a failed training is reported, not raised, so that the cases that need it fail
    with its error and the others go on.
    """
    in_process = isinstance(executor, SerialExecutor)
    wanted = {c.model_hash: c.config for c in cases if c.model_hash is not None}
    specs = {model_hash: {"config": config_to_dict(cfg), "store": str(store),
                          "cache_dir": str(cache_dir), "threads": threads, "progress": progress and in_process}
             for model_hash, cfg in wanted.items()}
    return {outcome.key: None if outcome.ok else f"model training failed: {outcome.error}"
            for outcome in executor.run(train_model, specs, desc="models", progress=progress if specs else False)}

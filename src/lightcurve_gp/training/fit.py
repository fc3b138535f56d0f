"""A training run, as a library: the training set, the fit on ``device``, the held-out metrics, the model file and
its metrics, into one run folder that appears whole.

:func:`train` is what ``python -m lightcurve_gp.train`` runs (the command adds its figures through ``also_write``
and its progress through ``run_step``) and what the model store (:func:`lightcurve_gp.training.store.get_or_train`)
trains with. The GP learns the targets of ``model.target`` (:func:`lightcurve_gp.training.sets.model_targets`);
the held-out metrics are computed on the same targets. Before anything is allocated, :func:`check_fit_memory`
refuses a fit that cannot fit in the device's free memory, in one line naming the key that sets its size.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, TypeVar

import torch
import yaml
from torch import Tensor

from lightcurve_gp.config.devices import available_memory
from lightcurve_gp.config.hashing import config_to_dict
from lightcurve_gp.config.schema import Config, ConfigError
from lightcurve_gp.files import RunFolder, file_sha256, write_json_atomic, write_text_atomic
from lightcurve_gp.observation import exact_gp, sparse_gp
from lightcurve_gp.observation.base import ObservationModel, Variance
from lightcurve_gp.observation.exact_gp import ExactGP, fast_variance_error
from lightcurve_gp.observation.serialization import build_model, save_model
from lightcurve_gp.training.keys import model_key, model_record
from lightcurve_gp.training.sets import (
    TrainingSet,
    generate_heldout_set,
    load_or_generate,
    model_targets,
    training_set_size,
)

__all__ = ["TrainingRun", "TrainingInterrupted", "heldout_metrics", "evaluate_model", "fit_memory",
           "check_fit_memory", "train", "TARGETS"]

T = TypeVar("T")
#: runs one long step (``fn``, a status text) and returns its result; a command passes its interruptible runner
StepRunner = Callable[[Callable[[], Any], str], Any]

#: what each ``model.target`` means, in words
TARGETS = {"magnitude": "target: magnitude",
           "rho_normalised": "target: magnitude normalised to model.rho_reference",
           "surface_normalised": "target: magnitude normalised to the reference surface's diffuse part, over "
                                 "data.surfaces"}


@dataclass
class TrainingRun:
    """What :func:`train` made: ``metrics`` (what ``metrics.json`` holds), the fitted ``model`` (on the config's
    device) and its held-out predictions, all ``(P,)`` on the CPU: the targets ``heldout.y``, the predictive
    ``mean`` and the predictive standard deviation ``std`` (latent variance plus noise, mag)."""

    metrics: dict[str, Any]
    model: ObservationModel
    heldout: TrainingSet
    mean: Tensor
    std: Tensor


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`train`; ``kept`` says what stayed on disk (a new training-data cache), empty when
    nothing did."""

    def __init__(self, kept: str = ""):
        super().__init__(kept)
        self.kept = kept


def heldout_metrics(mean: Tensor, var: Tensor | None, y: Tensor, noise_var: float) -> dict[str, float]:
    """Held-out metrics of a predictive distribution ``N(mean, var + noise_var)`` of targets ``y``, all ``(N,)``.

    ``var`` is the model's latent variance (``None``: zero) and ``noise_var = σ²`` its likelihood noise.

    Returns:
        ``rmse`` (mag), ``mae`` (mag), ``nlpd`` (mean negative log predictive density, nats), ``within_2sigma``
        (fraction of residuals inside ±2 predictive std), ``mean_std`` (mag), ``n``, and ``excess_variance``
        (mag²): the mean squared residual beyond the mean predictive variance, ``max(0, mean(r²) − mean(var_y))`` —
        the model error its own variance does not cover (``filter.model_error: heldout`` adds it to R).
    """
    var_y = (var if var is not None else torch.zeros_like(mean)) + noise_var
    resid = mean - y
    nlpd = 0.5 * (torch.log(2 * math.pi * var_y) + resid**2 / var_y)
    return {
        "n": int(y.numel()),
        "rmse": float(resid.pow(2).mean().sqrt()),
        "mae": float(resid.abs().mean()),
        "nlpd": float(nlpd.mean()),
        "within_2sigma": float((resid.abs() <= 2 * var_y.sqrt()).double().mean()),
        "mean_std": float(var_y.sqrt().mean()),
        "excess_variance": max(0.0, float(resid.pow(2).mean() - var_y.mean())),
    }


def evaluate_model(model: ObservationModel, data: TrainingSet, noise_var: float, *,
                   variance: Variance = "fast") -> dict[str, float]:
    """:func:`heldout_metrics` of ``model``'s predictions (with the ``variance`` choice) on ``data``."""
    with torch.no_grad():
        mean, var = model(q=data.q, m_past=data.m_past, variance=variance)
    return heldout_metrics(mean, var, data.y, noise_var)


def fit_memory(cfg: Config) -> tuple[int, str]:
    """Peak memory (bytes) of fitting the model of ``cfg`` and holding its training set, from the config alone, and
    what dominates it, in words."""
    points, conditioned = training_set_size(cfg)
    data = 8 * 16 * points  # the set (q, m_past, y, rho), its targets and the model's mapped inputs, float64
    if cfg.model.kind == "exact" and cfg.data.surfaces is None:
        return exact_gp.conditioning_bytes(conditioned) + data, "the exact GP's Cholesky factor (N^2 float64)"
    m = cfg.model.sparse.num_inducing
    return (sparse_gp.conditioning_bytes(conditioned, m) + data,
            f"the inducing-point GP's {m} x N kernels (model.sparse.num_inducing {m})")


def _size_key(cfg: Config) -> str:
    """The key that sets the training set's size, and its value: ``key: value``."""
    if cfg.data.sampling == "grid" and cfg.model.inputs != "body_geometry":
        return f"data.icosphere_subdivisions: {cfg.data.icosphere_subdivisions}"
    return f"data.num_random: {cfg.data.num_random}"


def check_fit_memory(cfg: Config, *, available: int | None = None) -> None:
    """Raise :class:`ConfigError` naming the key that sets the training set's size when :func:`fit_memory` exceeds
    ``available`` bytes (default: the free memory of ``cfg.device``, :func:`~lightcurve_gp.config.devices.
    available_memory`; nothing is checked when that is unknown)."""
    available = available_memory(cfg.device) if available is None else available
    need, what = fit_memory(cfg)
    if available is None or need <= available:
        return
    _, conditioned = training_set_size(cfg)
    other = "or use model.kind: sparse" if "exact" in what else "or lower model.sparse.num_inducing"
    key = _size_key(cfg)
    raise ConfigError(f"{key} gives up to {conditioned} training points (N); {what} needs {need / 1e9:.1f} GB and "
                      f"{cfg.device} has {available / 1e9:.1f} GB free: lower {key.partition(':')[0]} (or "
                      f"data.rho_grid's length) {other}")


def _run_direct(fn: Callable[[], T], status: str) -> T:
    return fn()


def _say(text: str, progress: bool) -> None:
    if progress:
        print(text, file=sys.stderr, flush=True)


def _noise_var(model: ObservationModel) -> float:
    noise = getattr(model, "noise", None)
    return float(noise) if noise is not None else 0.0


def _model_device(model: ObservationModel) -> torch.device:
    """The device the model's tensors are on (the device it was fitted on)."""
    first = next(iter(model.buffers()), None)
    return first.device if first is not None else torch.device("cpu")


def _fit(cfg: Config, cache_dir: Path, progress: bool, timings: dict, kept: list[str],
         run_step: StepRunner) -> tuple[ObservationModel, TrainingSet]:
    t0 = time.perf_counter()
    data, cache_path, loaded = load_or_generate(cfg, cache_dir, progress=progress)
    if not loaded:
        kept.append(f"kept the new training-data cache {cache_path}")
    timings["data_s"] = time.perf_counter() - t0
    _say(f"training set: {len(data)} points ({'loaded from' if loaded else 'generated into'} {cache_path}, "
         f"{data.dropped} zero-flux trajectories dropped) in {timings['data_s']:.1f} s", progress)
    t0 = time.perf_counter()
    data = model_targets(data, cfg.model)
    _say(f"fitting the {cfg.model.kind} GP on {len(data)} points ({TARGETS[cfg.model.target]}) on {cfg.device}",
         progress)
    surfaces = cfg.data.surfaces
    kwargs = {} if surfaces is None else {"per_attitude": surfaces.per_attitude,
                                          "spread_inducing": surfaces.spread_inducing}
    model = run_step(lambda: build_model(data.q, data.m_past, data.y, cfg.model, progress=progress,
                                         device=cfg.device, **kwargs), f"fitting the {cfg.model.kind} GP")
    timings["fit_s"] = time.perf_counter() - t0
    _say(f"fitted in {timings['fit_s']:.1f} s", progress)
    return model, data


def _predict(model: ObservationModel, heldout: TrainingSet, variance: Variance) -> tuple[Tensor, Tensor | None]:
    with torch.no_grad():
        return model(q=heldout.q, m_past=heldout.m_past, variance=variance)


def _evaluate(model: ObservationModel, cfg: Config, timings: dict, variance_check_points: int,
              run_step: StepRunner) -> tuple[TrainingSet, Tensor, Tensor, dict, dict | None]:
    t0 = time.perf_counter()
    heldout = model_targets(generate_heldout_set(cfg), cfg.model)
    on_device = heldout.to(device=_model_device(model))
    timings["heldout_data_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    mean, var = run_step(lambda: _predict(model, on_device, cfg.model.variance),
                         f"held-out prediction ({len(heldout)} points)")
    mean, var = mean.cpu(), None if var is None else var.cpu()
    metrics = heldout_metrics(mean, var, heldout.y, _noise_var(model))
    timings["heldout_predict_s"] = time.perf_counter() - t0
    variance_check = None
    if isinstance(model, ExactGP) and cfg.model.variance == "fast":
        k = min(variance_check_points, len(heldout))
        variance_check = run_step(lambda: fast_variance_error(model, on_device.q[:k], on_device.m_past[:k]),
                                  "fast-vs-exact variance check")
        variance_check["points"] = k
    if isinstance(model, ExactGP):
        model.drop_cholesky()  # the factor is N² floats: free it before saving and plotting
    std_y = ((var if var is not None else torch.zeros_like(mean)) + _noise_var(model)).sqrt()
    return heldout, mean, std_y, metrics, variance_check


def _fit_objective(model: ObservationModel) -> dict | None:
    """The fit's objective per point (evidence or SGPR bound, nats): its number of evaluations and last value;
    ``None`` without a fit."""
    history = getattr(model, "fit_history", None) or []
    return {"evaluations": len(history) - 1, "final": history[-1]} if history else None


def train(cfg: Config, run_dir: str | Path, cache_dir: str | Path, *, progress: bool = False,
          variance_check_points: int = 200, force: bool = False, record: dict | None = None,
          also_write: Callable[[Path, TrainingRun], None] | None = None,
          run_step: StepRunner | None = None) -> TrainingRun:
    """Train the model of ``cfg`` on ``cfg.device`` into the run folder ``run_dir``: ``model.pt``, ``config.yaml``
    (the resolved config) and ``metrics.json`` (held-out RMSE, mean negative log predictive density, fraction of
    residuals within 2σ, timings, the fit's evaluations and final objective, the device used, the model key and the
    model file's SHA-256, the seeds, and ``record`` under ``"run"``, e.g. the command's provenance).

    The folder appears atomically (:class:`~lightcurve_gp.files.RunFolder`): an interrupted or failed run leaves
    nothing, and an existing folder is refused unless ``force`` (then replaced at the end). ``also_write(folder,
    run)`` writes more files into the folder before it appears (a command's figures); ``run_step(fn, status)``
    runs each long step (default: calls it). A fit that cannot fit in memory is refused before anything is
    allocated (:func:`check_fit_memory`).

    Raises:
        ConfigError: the fit would not fit in the device's free memory.
        TrainingInterrupted: Ctrl-C; its ``kept`` names a training-data cache this run generated.
    """
    check_fit_memory(cfg)
    run_dir = Path(run_dir)
    kept: list[str] = []
    try:
        return _train_into(cfg, run_dir, Path(cache_dir), progress=progress, force=force, record=record,
                           variance_check_points=variance_check_points, kept=kept, also_write=also_write,
                           run_step=run_step or _run_direct)
    except KeyboardInterrupt:
        raise TrainingInterrupted("; ".join(kept + [f"{run_dir} not written"]) if kept else "") from None


def _train_into(cfg: Config, run_dir: Path, cache_dir: Path, *, progress: bool, force: bool, record: dict | None,
                variance_check_points: int, kept: list[str], also_write, run_step: StepRunner) -> TrainingRun:
    timings: dict[str, float] = {}
    with RunFolder(run_dir, force=force) as tmp:
        model, data = _fit(cfg, cache_dir, progress, timings, kept, run_step)
        heldout, mean, std_y, metrics, variance_check = _evaluate(model, cfg, timings, variance_check_points,
                                                                  run_step)
        save_model(model, tmp / "model.pt", extra={**model_record(cfg), "heldout": metrics})
        write_text_atomic(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), tmp / "config.yaml")
        result = {
            "name": cfg.name, "model": cfg.model.kind, "target": cfg.model.target,
            "rho_reference": cfg.model.rho_reference, "train_points": len(data),
            "heldout": metrics, "fast_variance_vs_exact": variance_check, "timings_s": timings,
            "fit_objective": _fit_objective(model), "device": str(_model_device(model)),
            "model_file": str(run_dir / "model.pt"), "model_key": model_key(cfg),
            "model_sha256": file_sha256(tmp / "model.pt"), "torch_threads": torch.get_num_threads(),
            "seeds": {"training_attitudes": cfg.data.seed, "heldout": cfg.data.seed + 1},
            "run": record or {},
        }
        write_json_atomic(result, tmp / "metrics.json")
        run = TrainingRun(result, model, heldout, mean, std_y)
        if also_write is not None:
            also_write(tmp, run)
    return run

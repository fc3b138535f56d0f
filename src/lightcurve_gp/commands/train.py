"""``python -m lightcurve_gp.train CONFIG``: generate (or load) the training set, fit the GP, evaluate it.

The GP learns the targets of ``model.target`` (:func:`lightcurve_gp.training.sets.model_targets`): magnitudes as in the
paper, or magnitudes normalised to ``model.rho_reference`` for the offset filter (``filter.estimate_offset``);
the held-out metrics are computed on the same targets.

Writes ``<out>/<name>/``: ``model.pt`` (the trained observation model), ``metrics.json`` (held-out RMSE, mean
negative log predictive density, fraction of residuals within 2σ, timings, the fit's evaluations and final
objective), ``config.yaml`` (the resolved config), ``heldout_scatter.png`` and ``heldout_residuals.png``. The folder
appears whole when the run ends (written into a temporary sibling, then renamed); an existing one is refused unless
``--force``, which replaces it only at the end and only when it holds nothing but these files. ``metrics.json``
records the model key (:mod:`lightcurve_gp.training.store`), the model file's SHA-256, the seeds, and under ``run`` the
command line, the exact config, the package/torch/Python versions and the thread count.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch
import yaml
from torch import Tensor

from lightcurve_gp.commands.common import (
    Interrupted,
    UserError,
    add_common_arguments,
    apply_threads,
    check_new_folder,
    check_output_root,
    check_overrides,
    exit_process,
    progress_enabled,
    provenance,
    run_command,
    run_interruptible,
)
from lightcurve_gp.config.load import Config, config_to_dict, load_config
from lightcurve_gp.evaluation.plots import prediction_scatter, residual_histogram, target_quantity
from lightcurve_gp.files import RunFolder, file_sha256, write_json_atomic, write_text_atomic
from lightcurve_gp.observation.base import ObservationModel, Variance
from lightcurve_gp.observation.exact_gp import ExactGP, fast_variance_error
from lightcurve_gp.observation.serialization import build_model, save_model
from lightcurve_gp.training.sets import TrainingSet, generate_heldout_set, load_or_generate, model_targets
from lightcurve_gp.training.store import model_key, model_record

__all__ = ["heldout_metrics", "evaluate_model", "train", "main"]


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


def _noise_var(model: ObservationModel) -> float:
    noise = getattr(model, "noise", None)
    return float(noise) if noise is not None else 0.0


def _fit(cfg: Config, cache_dir: Path, progress: bool, timings: dict,
         kept: list[str]) -> tuple[ObservationModel, TrainingSet]:
    t0 = time.perf_counter()
    data, cache_path, loaded = load_or_generate(cfg, cache_dir, progress=progress)
    if not loaded:
        kept.append(f"kept the new training-data cache {cache_path}")
    timings["data_s"] = time.perf_counter() - t0
    _say(f"training set: {len(data)} points ({'loaded from' if loaded else 'generated into'} {cache_path}, "
         f"{data.dropped} zero-flux trajectories dropped) in {timings['data_s']:.1f} s", progress)
    t0 = time.perf_counter()
    data = model_targets(data, cfg.model)
    _say(f"fitting the {cfg.model.kind} GP on {len(data)} points ({_TARGETS[cfg.model.target]})", progress)
    surfaces = cfg.data.surfaces
    kwargs = {} if surfaces is None else {"per_attitude": surfaces.per_attitude,
                                          "spread_inducing": surfaces.spread_inducing}
    model = run_interruptible(lambda: build_model(data.q, data.m_past, data.y, cfg.model, progress=progress,
                                                  **kwargs),
                              status=f"fitting the {cfg.model.kind} GP", progress=progress)
    timings["fit_s"] = time.perf_counter() - t0
    _say(f"fitted in {timings['fit_s']:.1f} s", progress)
    return model, data


def _predict(model: ObservationModel, heldout: TrainingSet, variance: Variance) -> tuple[Tensor, Tensor | None]:
    with torch.no_grad():
        return model(q=heldout.q, m_past=heldout.m_past, variance=variance)


def _evaluate(model: ObservationModel, cfg: Config, progress: bool, timings: dict,
              variance_check_points: int) -> tuple[TrainingSet, Tensor, Tensor, dict, dict | None]:
    t0 = time.perf_counter()
    heldout = model_targets(generate_heldout_set(cfg), cfg.model)
    timings["heldout_data_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    mean, var = run_interruptible(lambda: _predict(model, heldout, cfg.model.variance), progress=progress,
                                  status=f"held-out prediction ({len(heldout)} points)")
    metrics = heldout_metrics(mean, var, heldout.y, _noise_var(model))
    timings["heldout_predict_s"] = time.perf_counter() - t0
    variance_check = None
    if isinstance(model, ExactGP) and cfg.model.variance == "fast":
        k = min(variance_check_points, len(heldout))
        variance_check = run_interruptible(lambda: fast_variance_error(model, heldout.q[:k], heldout.m_past[:k]),
                                           status="fast-vs-exact variance check", progress=progress)
        variance_check["points"] = k
    if isinstance(model, ExactGP):
        model.drop_cholesky()  # the factor is N² floats: free it before saving and plotting
    std_y = ((var if var is not None else torch.zeros_like(mean)) + _noise_var(model)).sqrt()
    return heldout, mean, std_y, metrics, variance_check


def train(cfg: Config, run_dir: str | Path, cache_dir: str | Path, *, progress: bool = False,
          variance_check_points: int = 200, force: bool = False, record: dict | None = None) -> dict:
    """Run the whole training job for ``cfg`` into the run folder ``run_dir``; returns what ``metrics.json`` holds.

    The folder appears atomically (:class:`~lightcurve_gp.files.RunFolder`): an interrupted or failed run leaves
    nothing, and an existing folder is refused unless ``force`` (then replaced at the end). ``record`` (e.g.
    :func:`lightcurve_gp.commands.common.provenance`) is stored under ``"run"`` in ``metrics.json``, with the model
    key and the
    model file's SHA-256. Ctrl-C raises :class:`~lightcurve_gp.commands.common.Interrupted` saying what was kept (a
    training
    data cache generated by this run).
    """
    run_dir = Path(run_dir)
    kept: list[str] = []
    try:
        return _train_into(cfg, run_dir, Path(cache_dir), progress=progress, force=force, record=record,
                           variance_check_points=variance_check_points, kept=kept)
    except KeyboardInterrupt:
        raise Interrupted(kept="; ".join(kept + [f"{run_dir} not written"]) if kept else "") from None


def _train_into(cfg: Config, run_dir: Path, cache_dir: Path, *, progress: bool, force: bool, record: dict | None,
                variance_check_points: int, kept: list[str]) -> dict:
    timings: dict[str, float] = {}
    with RunFolder(run_dir, force=force) as tmp:
        model, data = _fit(cfg, cache_dir, progress, timings, kept)
        heldout, mean, std_y, metrics, variance_check = _evaluate(model, cfg, progress, timings,
                                                                  variance_check_points)
        save_model(model, tmp / "model.pt", extra={**model_record(cfg), "heldout": metrics})
        write_text_atomic(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), tmp / "config.yaml")
        prediction_scatter(heldout.y, mean, tmp / "heldout_scatter.png",
                           title=f"{cfg.name}: {cfg.model.kind} GP, held-out RMSE {metrics['rmse']:.3f} mag",
                           quantity=target_quantity(cfg.model.target, cfg.model.rho_reference))
        residual_histogram(mean - heldout.y, std_y, tmp / "heldout_residuals.png")
        result = {
            "name": cfg.name, "model": cfg.model.kind, "target": cfg.model.target, "train_points": len(data),
            "heldout": metrics, "fast_variance_vs_exact": variance_check, "timings_s": timings,
            "fit_objective": _fit_objective(model),
            "model_file": str(run_dir / "model.pt"), "model_key": model_key(cfg),
            "model_sha256": file_sha256(tmp / "model.pt"), "torch_threads": torch.get_num_threads(),
            "seeds": {"training_attitudes": cfg.data.seed, "heldout": cfg.data.seed + 1},
            "run": record or {},
        }
        write_json_atomic(result, tmp / "metrics.json")
    return result


def _fit_objective(model: ObservationModel) -> dict | None:
    """The fit's objective per point (evidence or SGPR bound, nats): its number of evaluations and last value;
    ``None`` without a fit."""
    history = getattr(model, "fit_history", None) or []
    return {"evaluations": len(history) - 1, "final": history[-1]} if history else None


_TARGETS = {"magnitude": "target: magnitude", "rho_normalised": "target: magnitude normalised to model.rho_reference",
            "surface_normalised": "target: magnitude normalised to the reference surface's diffuse part, over "
                                  "data.surfaces"}


def _say(text: str, progress: bool) -> None:
    if progress:
        print(text, file=sys.stderr, flush=True)


def _summary(result: dict) -> str:
    h = result["heldout"]
    rows = [
        ("model", f"{result['model']} GP, {result['train_points']} training points, {_TARGETS[result['target']]}"),
        ("held-out points", f"{h['n']} (random attitudes, rho off the grid)"),
        ("RMSE / MAE", f"{h['rmse']:.4f} / {h['mae']:.4f} mag"),
        ("mean NLPD", f"{h['nlpd']:.3f} nats"),
        ("within 2 sigma", f"{100 * h['within_2sigma']:.1f} %"),
    ]
    if result["fast_variance_vs_exact"]:
        v = result["fast_variance_vs_exact"]
        rows.append(("fast vs exact variance", ", ".join(f"{k} {val:.3g}" for k, val in v.items())))
    t = result["timings_s"]
    rows.append(("time", f"data {t['data_s']:.1f} s, fit {t['fit_s']:.1f} s, "
                          f"held-out prediction {t['heldout_predict_s']:.2f} s"))
    rows.append(("written", str(Path(result["model_file"]).parent)))
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k.ljust(width)}  {v}" for k, v in rows)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m lightcurve_gp.train",
        description="Generate or load the training set of CONFIG, fit its GP observation model (model.kind: exact "
                    "or sparse) and evaluate it on held-out trajectories with random attitudes and rho values off the "
                    "training grid. Writes the new folder OUT/<name>/ (model.pt, metrics.json, config.yaml, two "
                    "figures) atomically; an existing one is refused unless --force.",
    )
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing.yaml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value (repeatable), e.g. --set model.kind=sparse "
                             "--set data.t_span_past=10")
    parser.add_argument("--out", default="runs", type=Path, help="output folder (default: runs)")
    parser.add_argument("--cache", default=None, type=Path, help="training-data cache (default: OUT/cache)")
    add_common_arguments(parser)
    return parser


#: what a train run folder holds; --force replaces only a folder that holds nothing else
TRAIN_FILES = frozenset({"model.pt", "metrics.json", "config.yaml", "heldout_scatter.png", "heldout_residuals.png"})


def _check_replaceable(run_dir: Path) -> None:
    foreign = sorted(p.name for p in run_dir.iterdir() if p.name not in TRAIN_FILES) if run_dir.is_dir() else []
    if foreign:
        raise UserError(f"{run_dir} holds {', '.join(foreign)}, not written by train; --force replaces only a train "
                        f"run folder: move them away or choose another --out or name")


def _run(args: argparse.Namespace) -> int:
    apply_threads(args.threads)
    check_overrides(args.overrides)
    cfg = load_config(args.config, args.overrides)
    check_output_root(args.out)
    run_dir = args.out / cfg.name
    check_new_folder(run_dir, args.force)
    _check_replaceable(run_dir)
    progress = progress_enabled(args.no_progress)
    result = train(cfg, run_dir, args.cache or args.out / "cache", progress=progress, force=args.force,
                   record=provenance(cfg, seeds=[cfg.data.seed, cfg.data.seed + 1], config_file=str(args.config)))
    print(_summary(result))
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)


if __name__ == "__main__":
    exit_process(main())

"""``python -m lightcurve_gp.train CONFIG``: generate (or load) the training set, fit the GP, evaluate it.

The GP learns the targets of ``model.target`` (:func:`lightcurve_gp.data.model_targets`): magnitudes as in the
paper, or magnitudes normalised to ``model.rho_reference`` for the offset filter (``filter.estimate_offset``);
the held-out metrics are computed on the same targets.

Writes ``<out>/<name>/``: ``model.pt`` (the trained observation model), ``metrics.json`` (held-out RMSE, mean
negative log predictive density, fraction of residuals within 2σ, timings), ``config.yaml`` (the resolved
config), ``heldout_scatter.png`` and ``heldout_residuals.png``. Every file is written atomically.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch
import yaml

from .config import Config, ConfigError, config_to_dict, load_config
from .data import TrainingSet, generate_heldout_set, load_or_generate, model_targets
from .io import write_json_atomic, write_text_atomic
from .observation.base import ObservationModel
from .observation.exact_gp import ExactGP, fast_variance_error
from .observation.serialization import build_model, save_model
from .plots import prediction_scatter, residual_histogram

__all__ = ["evaluate_model", "train", "main"]


def evaluate_model(model: ObservationModel, data: TrainingSet, noise_var: float) -> dict[str, float]:
    """Held-out metrics of a model's predictive distribution of ``y``.

    The predictive distribution of a noise-free target is ``N(mean, var_f + noise_var)`` with ``var_f`` the
    model's latent variance and ``noise_var = σ²`` its likelihood noise.

    Returns:
        ``rmse`` (mag), ``mae`` (mag), ``nlpd`` (mean negative log predictive density, nats), ``within_2sigma``
        (fraction of residuals inside ±2 predictive std), ``mean_std`` (mag), ``n``.
    """
    with torch.no_grad():
        mean, var = model(q=data.q, m_past=data.m_past, with_variance=True)
    var_y = (var if var is not None else torch.zeros_like(mean)) + noise_var
    resid = mean - data.y
    nlpd = 0.5 * (torch.log(2 * math.pi * var_y) + resid**2 / var_y)
    return {
        "n": int(data.y.numel()),
        "rmse": float(resid.pow(2).mean().sqrt()),
        "mae": float(resid.abs().mean()),
        "nlpd": float(nlpd.mean()),
        "within_2sigma": float((resid.abs() <= 2 * var_y.sqrt()).double().mean()),
        "mean_std": float(var_y.sqrt().mean()),
    }


def _noise_var(model: ObservationModel) -> float:
    noise = getattr(model, "noise", None)
    return float(noise) if noise is not None else 0.0


def train(cfg: Config, out_dir: Path, cache_dir: Path, progress: bool = True,
          variance_check_points: int = 200) -> dict:
    """Run the whole training job for ``cfg`` and return the metrics written to ``metrics.json``."""
    run_dir = out_dir / cfg.name
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    data, cache_path, loaded = load_or_generate(cfg, cache_dir, progress=progress)
    timings["data_s"] = time.perf_counter() - t0
    _say(f"training set: {len(data)} points ({'loaded from' if loaded else 'generated into'} {cache_path}, "
         f"{data.dropped} zero-flux trajectories dropped) in {timings['data_s']:.1f} s")

    t0 = time.perf_counter()
    data = model_targets(data, cfg.model)
    _say(f"fitting the {cfg.model.kind} GP on {len(data)} points ({_TARGETS[cfg.model.target]}) ...")
    model = build_model(data.q, data.m_past, data.y, cfg.model, progress=progress)
    timings["fit_s"] = time.perf_counter() - t0
    _say(f"fitted in {timings['fit_s']:.1f} s")

    t0 = time.perf_counter()
    heldout = model_targets(generate_heldout_set(cfg), cfg.model)
    timings["heldout_data_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    metrics = evaluate_model(model, heldout, _noise_var(model))
    timings["heldout_predict_s"] = time.perf_counter() - t0

    variance_check = None
    if isinstance(model, ExactGP) and model.variance_mode == "fast":
        k = min(variance_check_points, len(heldout))
        variance_check = fast_variance_error(model, heldout.q[:k], heldout.m_past[:k])
        variance_check["points"] = k
    if isinstance(model, ExactGP):
        model.drop_cholesky()  # the factor is N² floats: free it before saving and plotting

    model_path = save_model(model, run_dir / "model.pt", extra={"config": config_to_dict(cfg)})
    write_text_atomic(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), run_dir / "config.yaml")
    with torch.no_grad():
        mean, var = model(q=heldout.q, m_past=heldout.m_past, with_variance=True)
    std_y = ((var if var is not None else torch.zeros_like(mean)) + _noise_var(model)).sqrt()
    prediction_scatter(heldout.y, mean, run_dir / "heldout_scatter.png",
                       title=f"{cfg.name}: {cfg.model.kind} GP, held-out RMSE {metrics['rmse']:.3f} mag")
    residual_histogram(mean - heldout.y, std_y, run_dir / "heldout_residuals.png")

    result = {
        "name": cfg.name,
        "model": cfg.model.kind,
        "target": cfg.model.target,
        "train_points": len(data),
        "heldout": metrics,
        "fast_variance_vs_exact": variance_check,
        "timings_s": timings,
        "model_file": str(model_path),
        "torch_threads": torch.get_num_threads(),
    }
    write_json_atomic(result, run_dir / "metrics.json")
    return result


_TARGETS = {"magnitude": "target: magnitude", "rho_normalised": "target: magnitude normalised to model.rho_reference"}


def _say(text: str) -> None:
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
                    "training grid. Writes OUT/<name>/ with model.pt, metrics.json, config.yaml and two figures.",
    )
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing.yaml")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value (repeatable), e.g. --set model.kind=sparse "
                             "--set data.t_span_past=10")
    parser.add_argument("--out", default="runs", type=Path, help="output folder (default: runs)")
    parser.add_argument("--cache", default=None, type=Path, help="training-data cache (default: OUT/cache)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = load_config(args.config, args.overrides)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    result = train(cfg, args.out, args.cache or args.out / "cache", progress=not args.no_progress)
    print(_summary(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())

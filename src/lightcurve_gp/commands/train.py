"""``python -m lightcurve_gp.train CONFIG``: generate (or load) the training set, fit the GP, evaluate it.

The training run itself is the library's :func:`lightcurve_gp.training.fit.train` (the GP learns the targets of
``model.target``, on ``cfg.device``); this command checks its inputs up front, adds the held-out figures and the
progress, and prints a summary.

Writes ``OUT/<name>/`` (:mod:`lightcurve_gp.commands.layout`): ``model.pt`` (the trained observation model),
``metrics.json`` (held-out RMSE, mean negative log predictive density, fraction of residuals within 2σ, timings, the
fit's evaluations and final objective, the device used), ``config.yaml`` (the resolved config),
``heldout_scatter.png`` and ``heldout_residuals.png``. The folder appears whole when the run ends (written into a
temporary sibling, then renamed); an existing one is refused unless ``--force``, which replaces it only at the end
and only when it holds nothing but these files. The model then goes into the model store ``OUT/models/<key>/``
(:func:`lightcurve_gp.training.store.add_to_store`, hard links), where ``sweep`` finds it. ``metrics.json``
records the model key (:mod:`lightcurve_gp.training.keys`), the model file's SHA-256, the seeds, and under ``run``
the command line, the exact config, the package/torch/Python versions and the thread count.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lightcurve_gp.commands.common import (
    Interrupted,
    UserError,
    add_common_arguments,
    apply_threads,
    check_new_folder,
    check_output_root,
    check_overrides,
    progress_enabled,
    provenance,
    run_command,
    run_interruptible,
)
from lightcurve_gp.commands.layout import check_run_name, data_cache, model_store, train_folder
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.plots import prediction_scatter, residual_histogram, target_quantity
from lightcurve_gp.training.fit import TARGETS, TrainingInterrupted, TrainingRun, check_fit_memory, train
from lightcurve_gp.training.store import add_to_store

__all__ = ["write_figures", "build_parser", "main", "TRAIN_FILES"]


def write_figures(folder: Path, run: TrainingRun) -> None:
    """The held-out figures of a training run, into its folder: predicted vs true, and the residuals."""
    prediction_scatter(run.heldout.y, run.mean, folder / "heldout_scatter.png",
                       title=f"{run.metrics['name']}: {run.metrics['model']} GP, held-out RMSE "
                             f"{run.metrics['heldout']['rmse']:.3f} mag",
                       quantity=target_quantity(run.metrics["target"], run.metrics["rho_reference"]))
    residual_histogram(run.mean - run.heldout.y, run.std, folder / "heldout_residuals.png")


def _summary(result: dict, store: Path) -> str:
    h = result["heldout"]
    rows = [
        ("model", f"{result['model']} GP, {result['train_points']} training points, {TARGETS[result['target']]}, "
                  f"fitted on {result['device']}"),
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
    rows.append(("model store", str(store)))
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k.ljust(width)}  {v}" for k, v in rows)


def build_parser(prog: str = "lightcurve-gp train") -> argparse.ArgumentParser:
    """The command's options; ``prog`` is how it was called (its usage line)."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Generate or load the training set of CONFIG, fit its GP observation model (model.kind: exact "
                    "or sparse) and evaluate it on held-out trajectories with random attitudes and rho values off the "
                    "training grid, on the config's device. Writes the new folder OUT/<name>/ (model.pt, "
                    "metrics.json, config.yaml, two figures) atomically; an existing one is refused unless --force. "
                    "The model also goes into the model store OUT/models/<model-key>/ (hard links), where sweep "
                    "finds it; estimate and sweep write beside it (OUT/estimates/<name>/, OUT/sweeps/<name>/), so "
                    "--force can always replace it.",
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
    check_run_name(cfg.name)
    check_fit_memory(cfg)
    check_output_root(args.out)
    run_dir = train_folder(args.out, cfg.name)
    check_new_folder(run_dir, args.force)
    _check_replaceable(run_dir)
    progress = progress_enabled(args.no_progress)
    try:
        run = train(cfg, run_dir, args.cache or data_cache(args.out), progress=progress, force=args.force,
                    record=provenance(cfg, seeds=[cfg.data.seed, cfg.data.seed + 1], config_file=str(args.config)),
                    also_write=write_figures,
                    run_step=lambda fn, status: run_interruptible(fn, status=status, progress=progress))
    except TrainingInterrupted as exc:
        raise Interrupted(kept=exc.kept) from None
    try:
        store = add_to_store(run_dir, cfg, model_store(args.out))
    except KeyboardInterrupt:
        raise Interrupted(kept=f"{run_dir} written; not added to the model store {model_store(args.out)}") from None
    print(_summary(run.metrics, store))
    return 0


def main(argv: list[str] | None = None, *, prog: str = "lightcurve-gp train") -> int:
    """Run the command on ``argv`` (default ``sys.argv[1:]``), its usage shown as ``prog``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)


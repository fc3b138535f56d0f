"""``python -m lightcurve_gp.estimate CONFIG --model runs/<name>/model.pt``: GPUKF vs UKF on the paper's scenario.

Runs the GPUKF (trained model), the conventional UKF (renderer with ``filter.rho_assumed``), the matched-ρ UKF
(an oracle knowing ``rho_true``) and the no-update baseline over ``--seeds`` noise realisations, prints median
and inter-quartile RMSE per axis, and writes to ``<out>/<name>/estimate_rho<rho>/``: ``results.json``,
``euler_errors.png`` and ``light_curves.png`` (seed 0, paper style: GPUKF blue, UKF red, observations black) and
``rmse_boxplot.png`` (all seeds).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from .config import ConfigError, load_config
from .estimation import DEFAULT_ESTIMATORS, ESTIMATORS, ScenarioResult, run_estimators
from .io import write_json_atomic
from .observation.serialization import ModelFileError, load_model
from .plots import euler_errors, light_curves, rmse_boxplot

__all__ = ["format_table", "write_outputs", "main"]

PAPER_STEP_SECONDS = {"gpukf": "0.83-0.88", "ukf": "0.003-0.007"}


def format_table(summary: dict) -> str:
    """Fixed-width table: estimator, median [IQR] RMSE per axis (deg), light-curve RMSE (mag), time per step."""
    head = (f"{'estimator':<12} {'yaw':>20} {'pitch':>20} {'roll':>20} {'<10deg':>7} {'LC rmse':>8} "
            f"{'NEES':>6} {'ms/step':>8} {'us/filter-step':>14}")
    lines = [f"rho_true = {summary['rho_true']:g}, {summary['seeds']} seeds, RMSE over "
             f"{summary['window_s'][0]:g}-{summary['window_s'][1]:g} s: median [q25, q75] in deg", head,
             "-" * len(head)]
    for name, e in summary["estimators"].items():
        cells = [f"{m:6.2f} [{a:5.2f},{b:5.2f}]" for m, a, b in
                 zip(e["rmse_deg_median"], e["rmse_deg_q25"], e["rmse_deg_q75"])]
        lines.append(f"{name:<12} {cells[0]:>20} {cells[1]:>20} {cells[2]:>20} "
                     f"{100 * e['fraction_all_axes_below_10deg']:6.0f}% {e['lc_rmse_noisy_median']:8.3f} "
                     f"{e['nees_mean']:6.2f} {1e3 * e['seconds_per_step']:8.3f} "
                     f"{1e6 * e['seconds_per_filter_step']:14.1f}")
    lo, hi = summary["nees_band_95"]
    lines.append(f"NEES: mean over the window and seeds (95 % band for a consistent filter: {lo:.2f}-{hi:.2f}); "
                 f"paper: {PAPER_STEP_SECONDS['gpukf']} s per GPUKF step, {PAPER_STEP_SECONDS['ukf']} s per UKF step")
    return "\n".join(lines)


def write_outputs(result: ScenarioResult, folder: Path, title: str = "") -> dict:
    """Write ``results.json`` and the three figures of one scenario into ``folder``; returns the summary."""
    sc = result.scenario
    summary = result.summary()
    summary["seed_values"] = list(sc.seeds)
    summary["per_seed_rmse_deg"] = {n: r.rmse_deg.tolist() for n, r in result.results.items()}
    write_json_atomic(summary, folder / "results.json")
    errors = {n: r.errors_deg[0] for n, r in result.results.items()}
    euler_errors(sc.times, errors, folder / "euler_errors.png", title=title, window=result.window)
    predictions = {n: r.history.y_pred[0] for n, r in result.results.items() if r.history is not None}
    light_curves(sc.times, sc.observations[0], predictions, folder / "light_curves.png", title=title)
    rmse_boxplot({n: r.rmse_deg for n, r in result.results.items()}, folder / "rmse_boxplot.png", title=title)
    return summary


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m lightcurve_gp.estimate",
        description="Estimate the attitude of the config's scenario with the GPUKF (a trained model file), the "
                    "conventional UKF (renderer with filter.rho_assumed), a matched-rho UKF and the no-update "
                    "baseline, over many noise seeds batched in one filter run each.",
    )
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing.yaml")
    parser.add_argument("--model", type=Path, help="trained model file (runs/<name>/model.pt); without it the "
                                                   "GPUKF is skipped")
    parser.add_argument("--seeds", type=int, default=None, help="number of noise seeds (default: scenario.seeds)")
    parser.add_argument("--rho-true", type=float, default=None, help="true rho (default: scenario.rho_true)")
    parser.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS),
                        help=f"comma-separated subset of {','.join(ESTIMATORS)} (default: "
                             f"{','.join(DEFAULT_ESTIMATORS)})")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value (repeatable)")
    parser.add_argument("--out", default="runs", type=Path, help="output folder (default: runs)")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads (default 1: small per-step tensors run fastest on one thread)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    torch.set_num_threads(max(1, args.threads))
    try:
        cfg = load_config(args.config, args.overrides)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    estimators = [e.strip() for e in args.estimators.split(",") if e.strip()]
    model = None
    if args.model is not None:
        try:
            model = load_model(args.model)
        except ModelFileError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    elif "gpukf" in estimators:
        print("note: no --model given, the GPUKF is skipped", file=sys.stderr)
        estimators.remove("gpukf")
    if args.seeds is not None and args.seeds < 1:
        print(f"error: --seeds: {args.seeds} must be >= 1", file=sys.stderr)
        return 2
    if args.rho_true is not None and not 0.0 <= args.rho_true <= 1.0:
        print(f"error: --rho-true: {args.rho_true:g} is outside [0, 1]", file=sys.stderr)
        return 2
    try:
        result = run_estimators(cfg, model, seeds=None if args.seeds is None else range(args.seeds),
                                rho_true=args.rho_true, estimators=estimators)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rho = result.scenario.rho_true
    folder = args.out / cfg.name / f"estimate_rho{rho:g}"
    summary = write_outputs(result, folder, title=f"rho_true = {rho:g}, rho_ukf = {cfg.filter.rho_assumed:g}")
    print(format_table(summary))
    print(f"written: {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``python -m lightcurve_gp.estimate CONFIG [--model runs/<name>/model.pt]``: the config's scenario estimated.

With ``--light-curve FILE [FILE ...]`` it estimates from light-curve files instead, by default with the whole-arc MAP
(:mod:`lightcurve_gp.commands.estimate_file`).

Without ``--estimators`` it runs the recommended estimator for the config and its noise
(:func:`~lightcurve_gp.evaluation.recommend.recommend_estimator`; it prints what it picked and why); ``--estimators
paper`` runs the paper's: the GPUKF (trained model), the conventional UKF (renderer with ``filter.rho_assumed``), the
matched-ρ UKF (an oracle knowing ``rho_true``) and the no-update baseline. Over ``--seeds`` noise realisations it
prints median and inter-quartile RMSE per axis with the Cramér–Rao bound, RMSE/CRB and the NEES beside them, and
writes to ``OUT/estimates/<name>/rho<rho>/`` (beside the training run ``OUT/<name>/``, never inside it:
:mod:`lightcurve_gp.commands.layout`): ``results.json`` (with the recommendation's line under ``run``),
``euler_errors.png`` and ``light_curves.png`` (seed 0, paper style: GPUKF blue, UKF red, observations black) and
``rmse_boxplot.png`` (all seeds).

Every scenario is simulated: the truth, its light curve and the noise come from the config (``scenario``) and the
seeds. Before any computation the command checks its inputs (config, estimator list, ``--model`` readable and
trained with the config's data and model settings — a mismatch names the first differing key unless
``--allow-model-mismatch`` — ``--out`` writable, the run folder new or ``--force``). The folder appears whole at
the end (temporary sibling, then rename); ``results.json`` records under ``run`` the command line, the exact
config, the model file and its SHA-256, the seeds, the package/torch/Python versions and the thread count.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from tqdm.auto import tqdm

from lightcurve_gp.commands.common import (
    UserError,
    add_common_arguments,
    apply_threads,
    available_memory,
    check_new_folder,
    check_output_root,
    check_overrides,
    format_bytes,
    progress_enabled,
    provenance,
    run_command,
    run_interruptible,
)
from lightcurve_gp.commands.estimate_file import add_file_arguments, check_options, run_on_file
from lightcurve_gp.commands.layout import estimate_folder
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.harness import ScenarioResult, check_estimators, run_estimators
from lightcurve_gp.evaluation.plots import euler_errors, light_curves, rmse_boxplot
from lightcurve_gp.evaluation.recommend import Recommendation, recommend_estimator
from lightcurve_gp.evaluation.registry import DEFAULT_ESTIMATORS, ESTIMATORS
from lightcurve_gp.evaluation.reporting import format_triple, scenario_summary
from lightcurve_gp.evaluation.scoring import nees_band
from lightcurve_gp.files import RunFolder, write_json_atomic
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario
from lightcurve_gp.simulation.truths import truth_material
from lightcurve_gp.training.store import check_model_matches, model_file_record, open_model, training_mismatch

__all__ = ["format_table", "against_band", "write_outputs", "run_bytes_per_seed", "main"]

PAPER_STEP_SECONDS = {"gpukf": "0.83-0.88", "ukf": "0.003-0.007"}
#: bytes one estimator keeps per seed and time step (history, scenario, scoring); measured: the peak RSS of this
#: command with the conventional UKF over 600 s grew by 1.2-1.7 MB per seed (100-300 seeds), 2.0-2.8 kB per step
BYTES_PER_STEP = 2048.0
#: float64 arrays of (sigma points x model points) one prediction holds at once (kernel row, exp, variance)
PREDICTION_ARRAYS = 3


def format_table(summary: dict) -> str:
    """Fixed-width table: estimator, median [IQR] RMSE per axis (deg), light-curve RMSE (mag), time per step."""
    width = max([12, *(len(name) for name in summary["estimators"])])
    head = (f"{'estimator':<{width}} {'yaw':>20} {'pitch':>20} {'roll':>20} {'<10deg':>7} {'LC rmse':>8} "
            f"{'NEES':>6} {'ms/step':>8} {'us/filter-step':>14}")
    lines = [f"rho_true = {summary['rho_true']:g}, {summary['seeds']} seeds, RMSE over "
             f"{summary['window_s'][0]:g}-{summary['window_s'][1]:g} s: median [q25, q75] in deg", head,
             "-" * len(head)]
    for name, e in summary["estimators"].items():
        cells = [f"{m:6.2f} [{a:5.2f},{b:5.2f}]" for m, a, b in
                 zip(e["rmse_deg_median"], e["rmse_deg_q25"], e["rmse_deg_q75"])]
        lines.append(f"{name:<{width}} {cells[0]:>20} {cells[1]:>20} {cells[2]:>20} "
                     f"{100 * e['fraction_all_axes_below_10deg']:6.0f}% {e['lc_rmse_noisy_median']:8.3f} "
                     f"{e['nees_mean']:6.2f} {1e3 * e['seconds_per_step']:8.3f} "
                     f"{1e6 * e['seconds_per_filter_step']:14.1f}")
    lo, hi = summary["nees_band_95"]
    lo1, hi1 = nees_band()
    mean_band, seed_band = f"mean's band {lo:.2f}-{hi:.2f}", f"seeds in {lo1:.2f}-{hi1:.2f}"
    lines.append(f"{'':<{width}} {'CRB yaw / pitch / roll':>24} {'median RMSE/CRB':>17} {'NEES mean':>10} "
                 f"{mean_band:>22} {'median':>7} {seed_band:>18}")
    for name, e in summary["estimators"].items():
        share = e["share_nees_in_band"]
        crb, ratio = format_triple(e["crb_deg_median"], 2), format_triple(e["rmse_over_crb"], 1)
        lines.append(f"{name:<{width}} {crb:>24} {ratio:>17} {e['nees_mean']:10.2f} "
                     f"{against_band(e['nees_mean'], lo, hi):>22} {e['nees_median']:7.2f} "
                     f"{'-' if math.isnan(share) else f'{100 * share:.0f}%':>18}")
    if summary.get("omega_estimated"):
        lines.append("body rate estimated: median omega RMSE over the window / final omega error (deg/s), mean NEES "
                     "of [attitude, omega] (95 % band)")
        for name, e in summary["estimators"].items():
            band = "{:.2f}-{:.2f}".format(*e["nees_full_band_95"])
            lines.append(f"  {name:<12} {e['omega_rmse_deg_s_median']:.4f} / {e['omega_error_final_deg_s_median']:.4f}"
                         f"   NEES {e['nees_full_mean']:.2f} ({band})")
    lines += [f"  {note}" for note in COLUMN_NOTES]
    lines.append(f"  NEES bands (95 %, consistent filter): of the mean over these {summary['seeds']} seeds "
                 f"{lo:.2f}-{hi:.2f}; of one seed {lo1:.2f}-{hi1:.2f}. Paper: {PAPER_STEP_SECONDS['gpukf']} s per "
                 f"GPUKF step, {PAPER_STEP_SECONDS['ukf']} s per UKF step")
    return "\n".join(lines)


def against_band(value: float, lo: float, hi: float) -> str:
    """Where ``value`` lies against the band ``[lo, hi]``: ``below``, ``inside``, ``above`` (``-`` for NaN)."""
    if math.isnan(value):
        return "-"
    return "below" if value < lo else "above" if value > hi else "inside"


COLUMN_NOTES = (
    "yaw/pitch/roll: RMSE of the 3-2-1 Euler-angle error over the scoring window, per seed; median [q25, q75] "
    "over the seeds, deg",
    "<10deg: share of seeds whose RMSE is below 10 deg on all three axes",
    "LC rmse: median over seeds of the RMS difference between the estimator's predicted and the observed (noisy) "
    "light curve, mag (NaN for no_update, which predicts none)",
    "NEES: normalised estimation error squared of the 3-dof attitude error, each seed's mean over the window, then "
    "the mean over the seeds (3 for a consistent filter)",
    "CRB: the Cramer-Rao bound of the same problem (the estimator's unknowns, the filters' prior; the filtering bound "
    "for filters, the smoothing bound for the whole-arc MAP), RMS over the window, median over the seeds, deg",
    "median RMSE/CRB: the median over the seeds of the RMSE over the median CRB, per axis. The bound holds for the "
    "mean squared error averaged over the noise and over initial errors drawn from the prior P0; the scenario's "
    "initial error is one fixed value (scenario.initial_error_deg) and a median is not a root mean square, so a ratio "
    "below 1 means errors smaller than the prior's average case, not a broken bound",
    "NEES mean against the mean's band: below, inside or above the 95 % band of a mean of this many seeds' NEES "
    "for a consistent filter (each seed's average one chi-square(3) draw); below: the covariance is larger than the "
    "errors (under-confident), above: smaller (over-confident)",
    "NEES median and seeds in: the median over the seeds of each seed's NEES, and the share of seeds inside the "
    "95 % band of one seed's (one chi-square(3) draw: a seed's errors are correlated over the window); every seed "
    "can lie inside this wide band while their mean lies outside the narrow band of a mean",
    "ms/step: wall time of one filter step for all seeds in one batch; us/filter-step: the same per seed",
)


def write_outputs(result: ScenarioResult, folder: Path, title: str = "", record: dict | None = None) -> dict:
    """Write ``results.json`` and the three figures of one scenario into ``folder``; returns the summary.

    ``record`` (the run's provenance: command line, config, model file and its hash...) is stored under ``"run"``.
    """
    sc = result.scenario
    summary = scenario_summary(result)
    summary["seed_values"] = list(sc.seeds)
    summary["per_seed_rmse_deg"] = {n: r.rmse_deg.tolist() for n, r in result.results.items()}
    summary["columns"] = list(COLUMN_NOTES)
    for entry in summary["estimators"].values():  # the table's "mean's band" column, for readers of the file
        entry["nees_mean_against_band_95"] = against_band(entry["nees_mean"], *summary["nees_band_95"])
    summary["run"] = record or {}
    write_json_atomic(summary, folder / "results.json")
    first = ", ".join(filter(None, (title, f"noise seed {sc.seeds[0]}")))
    errors = {n: r.errors_deg[0] for n, r in result.results.items() if r.trajectory}  # not the MAP's checkpoints
    euler_errors(sc.times, errors, folder / "euler_errors.png", title=first, window=result.window)
    predictions = {n: r.history.y_pred[0] for n, r in result.results.items() if r.history is not None}
    light_curves(sc.times, sc.observations[0], predictions, folder / "light_curves.png", title=first)
    rmse_boxplot({n: r.rmse_deg for n, r in result.results.items()}, folder / "rmse_boxplot.png", title=title)
    return summary


def build_parser(prog: str = "lightcurve-gp estimate") -> argparse.ArgumentParser:
    """The command's options; ``prog`` is how it was called (its usage line)."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Estimate the attitude of the config's simulated scenario over many noise seeds batched in one "
                    "run per estimator: the recommended estimator for the config and its noise (printed with the "
                    "reason), or --estimators (paper: the GPUKF, the conventional UKF, a matched-rho UKF and the "
                    "no-update baseline). Writes the new folder "
                    "OUT/estimates/<name>/rho<rho>/ (results.json, three figures) atomically, beside the training "
                    "run OUT/<name>/ (never inside it); an existing one is refused unless --force. With "
                    "--light-curve: OUT/estimates/<name>/light_curve_<file stem>/.",
    )
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing.yaml")
    parser.add_argument("--model", type=Path, help="trained model file (runs/<name>/model.pt); required by the "
                                                   "gpukf estimator")
    parser.add_argument("--seeds", type=int, default=None, help="number of noise seeds (default: scenario.seeds)")
    parser.add_argument("--rho-true", type=float, default=None, help="true rho in (0, 1] (default: scenario.rho_true)")
    parser.add_argument("--estimators", default=None,
                        help=f"comma-separated subset of {','.join(ESTIMATORS)}, or paper (= "
                             f"{','.join(DEFAULT_ESTIMATORS)}, without gpukf when no --model is given) (default: the "
                             f"recommended estimator for the config and its noise, printed with the reason)")
    parser.add_argument("--allow-model-mismatch", action="store_true",
                        help="run a model trained with other data/model settings than the config's (recorded in "
                             "results.json)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value (repeatable)")
    parser.add_argument("--out", default="runs", type=Path, help="output folder (default: runs)")
    add_file_arguments(parser)
    add_common_arguments(parser)
    return parser


def _estimators(text: str | None, have_model: bool) -> list[str]:
    if text is None or text.strip() == "paper":
        return [e for e in DEFAULT_ESTIMATORS if have_model or e != "gpukf"]
    names = [e.strip() for e in text.split(",") if e.strip()]
    if not names:
        raise UserError(f"--estimators: {text!r} names no estimator; choose from {', '.join(ESTIMATORS)}")
    unknown = [e for e in names if e not in ESTIMATORS]
    if unknown:
        raise UserError(f"--estimators: unknown estimator {unknown[0]!r}; choose from {', '.join(ESTIMATORS)}")
    if "gpukf" in names and not have_model:
        raise UserError("--model: the gpukf estimator needs a trained model file (python -m lightcurve_gp.train)")
    return list(dict.fromkeys(names))


def _check_numbers(args: argparse.Namespace) -> None:
    if args.seeds is not None and args.seeds < 1:
        raise UserError(f"--seeds: {args.seeds} must be >= 1")
    if args.rho_true is not None and not 0.0 < args.rho_true <= 1.0:
        raise UserError(f"--rho-true: {args.rho_true:g} is outside (0, 1]")


def _load_checked_model(args: argparse.Namespace, cfg) -> tuple[object | None, dict]:
    """The model file (checked against the config unless --allow-model-mismatch) and its provenance record."""
    if args.model is None:
        return None, {"model_file": None}
    model = open_model(args.model)
    mismatch = training_mismatch(model, cfg)
    if mismatch is not None and not args.allow_model_mismatch:
        check_model_matches(model, cfg, args.model)
    return model, {**model_file_record(args.model), "model_key": model.extra.get("model_key"),
                   "allow_model_mismatch": args.allow_model_mismatch, "model_mismatch": mismatch}


def run_bytes_per_seed(*, steps: int, estimators: int, state_dim: int, model_points: int) -> float:
    """A lower bound of the memory (bytes) one seed adds to the batched run: every estimator's record of ``steps``
    time steps (:data:`BYTES_PER_STEP`) and one prediction of the ``2 state_dim + 1`` sigma points against the
    GP's ``model_points`` training or inducing points (:data:`PREDICTION_ARRAYS` float64 arrays)."""
    return steps * estimators * BYTES_PER_STEP + PREDICTION_ARRAYS * 8.0 * (2 * state_dim + 1) * model_points


def _check_memory(cfg, model, seeds: int, estimators: list[str]) -> None:
    """Refuse, before anything is allocated, a batch of ``seeds`` that cannot fit in the device's free memory."""
    steps = round(cfg.scenario.duration_s / cfg.scenario.dt_s) + 1
    state_dim = 3 + 3 * int(cfg.filter.estimate_omega) + int(cfg.filter.estimate_offset)
    points = int(getattr(model, "num_train", 0) or getattr(model, "num_inducing", 0)) if model is not None else 0
    per_seed = run_bytes_per_seed(steps=steps, estimators=len(estimators), state_dim=state_dim, model_points=points)
    free = available_memory(cfg.device)
    if seeds * per_seed > free:
        raise UserError(f"--seeds: {seeds} seeds need about {format_bytes(seeds * per_seed)} for the batched run "
                        f"({format_bytes(per_seed)} per seed), more than the {format_bytes(free)} available; use "
                        f"--seeds {int(free // per_seed)} or fewer")


def _run_all(cfg, model, estimators: list[str], args: argparse.Namespace, progress: bool) -> ScenarioResult:
    """The scenario, then each estimator in turn (a progress bar over them), interruptible, merged into one
    result."""
    seeds = None if args.seeds is None else range(args.seeds)
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=seeds, rho_true=args.rho_true, scene=scene)
    check_estimators(cfg, estimators, model, along_pass=sc.geometry is not None)
    merged: ScenarioResult | None = None
    for name in tqdm(estimators, desc="estimators", unit="filter", disable=not progress):
        part = run_interruptible(lambda n=name: run_estimators(cfg, sc, estimators=[n], model=model, scene=scene),
                                 status=f"running {name}", progress=progress)
        merged = part if merged is None else merged
        merged.results.update(part.results)
    assert merged is not None
    return merged


def _announce(recommended: Recommendation | None) -> None:
    """Say which estimator runs by default and why (one line), and how to run the paper's."""
    if recommended is not None:
        print(f"{recommended.line()} (--estimators paper: the paper's estimators)", flush=True)


def _run(args: argparse.Namespace) -> int:
    apply_threads(args.threads)
    check_overrides(args.overrides)
    check_options(args)
    _check_numbers(args)
    cfg = load_config(args.config, args.overrides)
    if args.light_curve is not None:  # observed light curves: the whole-arc MAP by default (estimate_file)
        return run_on_file(args, cfg, *_load_checked_model(args, cfg))
    recommended = None
    if args.estimators is None:
        try:
            recommended = recommend_estimator(cfg, noise_std=math.sqrt(cfg.scenario.noise_var),
                                              have_model=args.model is not None)
        except ValueError as exc:
            raise UserError(str(exc)) from exc
        estimators = [recommended.name]
    else:
        estimators = _estimators(args.estimators, args.model is not None)
    model, model_info = _load_checked_model(args, cfg)
    check_output_root(args.out)
    rho = truth_material(cfg, args.rho_true)[0]
    folder = estimate_folder(args.out, cfg.name, rho)
    check_new_folder(folder, args.force)
    n_seeds = args.seeds if args.seeds is not None else cfg.scenario.seeds
    _check_memory(cfg, model, n_seeds, estimators)
    seeds = list(range(n_seeds))
    record = provenance(cfg, seeds=seeds, config_file=str(args.config), estimators=estimators, rho_true=rho,
                        recommended=None if recommended is None else recommended.line(), **model_info)
    _announce(recommended)
    try:
        result = _run_all(cfg, model, estimators, args, progress_enabled(args.no_progress))
    except ValueError as exc:  # e.g. a model whose target the filter cannot use
        raise UserError(str(exc)) from exc
    with RunFolder(folder, force=args.force) as tmp:
        summary = write_outputs(result, tmp, title=f"rho_true = {rho:g}, rho_ukf = {cfg.filter.rho_assumed:g}",
                                record=record)
    print(format_table(summary))
    print(f"written: {folder}")
    return 0


def main(argv: list[str] | None = None, *, prog: str = "lightcurve-gp estimate") -> int:
    """Run the command on ``argv`` (default ``sys.argv[1:]``), its usage shown as ``prog``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)


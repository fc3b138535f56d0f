"""``python -m lightcurve_gp.sweep``: the command line of :func:`~lightcurve_gp.sweep.runner.run_sweep`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lightcurve_gp.commands.common import (
    Interrupted,
    UserError,
    add_common_arguments,
    apply_threads,
    check_overrides,
    progress_enabled,
    run_command,
)
from lightcurve_gp.commands.layout import data_cache, model_store, sweeps_root
from lightcurve_gp.config.load import config_from_dict, load_raw_config
from lightcurve_gp.evaluation.registry import DEFAULT_ESTIMATORS, ESTIMATORS
from lightcurve_gp.sweep.executors import CLUSTER_EXTRA, EXECUTORS
from lightcurve_gp.sweep.grid import parse_grid
from lightcurve_gp.sweep.runner import SweepResult, run_sweep
from lightcurve_gp.sweep.tables import print_summary

__all__ = ["build_parser", "main"]


def build_parser(prog: str = "lightcurve-gp sweep") -> argparse.ArgumentParser:
    """The command's options; ``prog`` is how it was called (its usage line)."""
    parser = argparse.ArgumentParser(
        prog=prog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the estimators (GPUKF, conventional UKF, matched-rho UKF, no-update baseline) over the "
                    "cartesian product of grid axes, every case with all seeds batched.",
        epilog="""\
what it does:
  * every grid point is applied to CONFIG (after --set) and validated before anything runs; an unknown key or a bad
    value stops the sweep with an error naming the key
  * one GP per distinct geometry/shape/surface/data/model setting comes from the model store OUT/models/<key>/
    (python -m lightcurve_gp.train's models are there too) or is trained into it once, for every later use
  * each case is stored when it finishes, atomically, in OUT/sweeps/<name>/cases/<case-id>.json (the id hashes the
    case's whole config, seeds and estimators); a rerun skips stored cases and retries failed ones, so an
    interrupted sweep (Ctrl-C) resumes where it stopped
  * a case that raises is recorded with its error (status "failed") and the sweep goes on; a case whose worker
    process died is run again (--retries times at most)
  * --executor dask runs the trainings, then the cases, as tasks on a dask.distributed cluster; the records come
    back to this process, which stores each as it arrives (a rerun with either executor resumes the store)
  * tables in OUT/sweeps/<name>/sweep/<sweep-id>/: results.csv (one row per case x seed x estimator: case_id, the grid
    values, seed, estimator, rmse_yaw_deg, rmse_pitch_deg, rmse_roll_deg, lc_rmse_noisy, lc_rmse_clean,
    nees_mean, seconds_per_step, status, error), summary.csv / summary.json (median and quartiles per case and
    estimator) and sweep.json (the definition); nothing goes into a training run's folder OUT/<name>/

example:
  python -m lightcurve_gp.sweep configs/boxwing.yaml --grid data.t_span_past=10,20,30,40 \\
      --grid scenario.rho_true=0.3,0.7 --seeds 20 --set filter.add_model_variance=false
  python -m lightcurve_gp.sweep configs/boxwing.yaml --grid scenario.rho_true=0.3,0.7 --seeds 100 \\
      --executor dask --workers 2                      # a LocalCluster; or --scheduler tcp://head:8786
""")
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing.yaml")
    parser.add_argument("--grid", action="append", default=[], metavar="KEY.PATH=V1,V2,...",
                        help="a grid axis (repeatable): any config key and its values, parsed as YAML "
                             "(e.g. scenario.rho_true=0.3,0.7 or scenario.initial_error_deg=[-10,5,-10],[5,5,5])")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value for every case (repeatable)")
    parser.add_argument("--seeds", type=int, default=None,
                        help="number of noise seeds 0..N-1 per case (default: scenario.seeds)")
    parser.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS),
                        help=f"comma-separated subset of {','.join(ESTIMATORS)} (default: "
                             f"{','.join(DEFAULT_ESTIMATORS)})")
    parser.add_argument("--out", default="runs", type=Path, help="output root (default: runs)")
    parser.add_argument("--cache", default=None, type=Path, help="training-data cache (default: OUT/cache)")
    parser.add_argument("--sweep-id", default=None,
                        help="table folder OUT/sweeps/<name>/sweep/<id> (default: hash of the definition)")
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="where trainings and cases run: local (a pool of --workers spawned processes, or this "
                             "process with 1) or dask (dask.distributed: a LocalCluster of --workers "
                             "single-threaded processes, or the running scheduler of --scheduler; needs the cluster "
                             f"extra, {CLUSTER_EXTRA}) (default local)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of a running dask scheduler, e.g. tcp://head:8786 (with --executor dask; every "
                             "worker must see OUT)")
    parser.add_argument("--workers", type=int, default=1,
                        help="worker processes of the local pool or the LocalCluster (default 1)")
    parser.add_argument("--retries", type=int, default=2,
                        help="times a case or training whose worker process died is run again (default 2)")
    parser.add_argument("--no-retry", action="store_true", help="keep stored failures instead of retrying them")
    add_common_arguments(parser, force=False)
    return parser


def _run(args: argparse.Namespace) -> int:
    threads = apply_threads(args.threads)
    check_overrides(args.overrides)
    if args.seeds is not None and args.seeds < 1:
        raise UserError(f"--seeds: {args.seeds} must be >= 1")
    raw = load_raw_config(args.config, args.overrides)
    axes = [parse_grid(g) for g in args.grid]
    estimators = [e.strip() for e in args.estimators.split(",") if e.strip()]
    base = config_from_dict(raw)
    seeds = range(args.seeds if args.seeds is not None else base.scenario.seeds)
    out = sweeps_root(args.out)
    cases_folder = out / base.name / "cases"
    try:
        result = run_sweep(raw, axes, seeds, out=out, store=model_store(args.out), sweep_id=args.sweep_id,
                           estimators=estimators, workers=args.workers, threads=threads,
                           cache_dir=args.cache or data_cache(args.out),
                           progress=progress_enabled(args.no_progress), rerun_failed=not args.no_retry,
                           executor=args.executor, scheduler=args.scheduler, retries=args.retries)
    except KeyboardInterrupt:
        raise Interrupted(f"finished cases are stored in {cases_folder}; rerun the same command to resume") from None
    if result.interrupted:
        raise Interrupted(_kept(result, [k for k, _ in axes], cases_folder))
    print_summary(result.summary, [k for k, _ in axes])
    for cid in result.failed:
        print(f"case {cid} failed: {result.records[cid].error}", file=sys.stderr)
    print(f"written: {result.folder}")
    return 1 if result.failed else 0


def _kept(result: SweepResult, grid_keys: list[str], cases_folder: Path) -> str:
    """What an interrupted sweep kept: the table of its stored cases (printed when there is one) and the line of
    the interrupt."""
    stored, total = len(result.records), len(result.cases)
    if not stored:
        return f"no case finished (0 of {total}); rerun the same command to start again"
    print(f"kept so far: {stored} of {total} cases")
    print_summary(result.summary, grid_keys)
    return (f"{stored} of {total} cases stored in {cases_folder} (partial tables in {result.folder}); rerun the same "
            f"command to resume")


def main(argv: list[str] | None = None, *, prog: str = "lightcurve-gp sweep") -> int:
    """Run the command on ``argv`` (default ``sys.argv[1:]``), its usage shown as ``prog``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)

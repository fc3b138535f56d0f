"""The command-line arguments the experiments share: the robust config's, and those of a sweep's executor."""

from __future__ import annotations

import argparse
from pathlib import Path

from lightcurve_gp.sweep.executors import CLUSTER_EXTRA, EXECUTORS

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["ROOT", "robust_arguments", "sweep_arguments"]


def sweep_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of a sweep's executor (see :func:`lightcurve_gp.sweep.make_executor`), threads and progress."""
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="local (this machine) or dask (a LocalCluster of --workers processes, or --scheduler; "
                             f"needs {CLUSTER_EXTRA}) (default local)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of a running dask scheduler (with --executor dask)")
    parser.add_argument("--workers", type=int, default=1,
                        help="worker processes of the local pool or the LocalCluster (default 1)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads of the command and of each case process "
                        "(default 1)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return parser


def robust_arguments(description: str, *, seeds: int, seed_start: int, seed_help: str) -> argparse.ArgumentParser:
    """``--config``, ``--seeds``, ``--seed-start``, ``--out`` (committed summaries) and ``--runs`` (trained
    models)."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--config", default=str(ROOT / "configs/boxwing_robust.yaml"))
    p.add_argument("--seeds", type=int, default=seeds, help=f"noise seeds (default {seeds})")
    p.add_argument("--seed-start", type=int, default=seed_start,
                   help=f"first noise seed (default {seed_start}: {seed_help})")
    p.add_argument("--out", default=str(ROOT / "experiments/results/robust"), type=Path)
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path, help="where trained models are kept")
    return p
